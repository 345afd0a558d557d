"""Before/after render servers asked in turn (``ab_cpu``, ``ab_path``): one process per checkout,
started once, each printing ``ready`` and then one JSON line per request; the driver alternates
the order of the requests, so both checkouts see the same machine."""

from __future__ import annotations

import json
import subprocess


def ask_in_turn(commands: dict, repeats: int) -> dict:
    """name -> list of the ``repeats`` answers (dicts) of the server ``commands[name]`` = (argv, cwd)."""
    servers = {name: subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=cwd)
               for name, (argv, cwd) in commands.items()}
    for server in servers.values():
        while server.stdout.readline().strip() != "ready":
            pass
    answers = {name: [] for name in servers}
    for r in range(repeats):
        for name in (list(servers) if r % 2 == 0 else list(servers)[::-1]):
            servers[name].stdin.write("go\n")
            servers[name].stdin.flush()
            answers[name].append(json.loads(servers[name].stdout.readline()))
    for server in servers.values():
        server.stdin.close()
        server.wait()
    return answers
