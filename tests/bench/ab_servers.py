"""Before/after render servers asked in turn (``ab_cpu``, ``ab_path``, ``ab_bars``, ``ab_parent``, ``ab_floor``):
one process per checkout, started once, each printing ``ready`` and then one JSON line per request
line (:func:`answer_requests`); the driver alternates the order of the requests and of the servers,
so both checkouts see the same machine."""

from __future__ import annotations

import json
import subprocess
import sys
from typing import Callable, TextIO


def answer_requests(answer: Callable[[str], object], out: TextIO | None = None) -> None:
    """The server's side, once its checkout is set up: ``ready``, then per request line on stdin
    (stripped) the JSON of ``answer(request)`` on ``out`` (default stdout), until stdin closes."""
    out = sys.stdout if out is None else out
    print("ready", file=out, flush=True)
    for line in sys.stdin:
        print(json.dumps(answer(line.strip())), file=out, flush=True)


def ask_each_in_turn(commands: dict, repeats: int, requests: tuple[str, ...]) -> dict:
    """(name, request) -> list of the ``repeats`` answers (dicts) of the server ``commands[name]`` =
    (argv, cwd) to the request line ``request``."""
    servers = {name: subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=cwd)
               for name, (argv, cwd) in commands.items()}
    for server in servers.values():
        while server.stdout.readline().strip() != "ready":
            pass
    answers = {(name, request): [] for name in servers for request in requests}
    for r in range(repeats):
        for request in (requests if r % 2 == 0 else requests[::-1]):
            for name in (list(servers) if r % 2 == 0 else list(servers)[::-1]):
                servers[name].stdin.write(request + "\n")
                servers[name].stdin.flush()
                answers[(name, request)].append(json.loads(servers[name].stdout.readline()))
    for server in servers.values():
        server.stdin.close()
        server.wait()
    return answers


def ask_in_turn(commands: dict, repeats: int) -> dict:
    """name -> list of the ``repeats`` answers of the server ``commands[name]`` to one kind of request."""
    answers = ask_each_in_turn(commands, repeats, ("go",))
    return {name: answers[(name, "go")] for name in commands}
