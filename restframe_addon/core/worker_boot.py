"""First code of a tile worker process (:mod:`.workers`): its main script, run by path
(``python -I worker_boot.py``) before any package exists.

The parent sends one pickle of plain values on stdin: its ``sys.path``, the module of the
worker loop and the packages above RESTframe's own with their folders.  Inside Blender the
extension's package is ``bl_ext.<repo>.<id>``, which Blender creates in memory at run time:
those parents are registered here as empty packages with their ``__path__`` (their
``__init__`` imports bpy and is not run), so the pickles the parent sends, which name
``bl_ext.<repo>.<id>.restframe_addon.core...``, import the very same files.

Only stdlib modules are imported here.  Results go back on a copy of stdout; fd 1 itself
then points at stderr, so nothing printed in the worker can corrupt the stream.
"""

import importlib
import importlib.machinery
import os
import pickle
import signal
import sys
import types


def main():
    # Ctrl-C in a terminal signals the whole process group: the parent decides what stops (it
    # cancels the tiles, or exits and so closes the pipes), a worker never dies of it mid-tile
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    commands = sys.stdin.buffer
    results = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    boot = pickle.load(commands)
    sys.path[:] = boot["path"]
    for name, folders in boot["parents"]:
        package = types.ModuleType(name)
        package.__path__ = list(folders)
        package.__package__ = name
        package.__spec__ = importlib.machinery.ModuleSpec(name, None, is_package=True)
        package.__spec__.submodule_search_locations = package.__path__
        sys.modules[name] = package
    importlib.import_module(boot["module"]).serve(commands, results, boot["parent_pid"])


main()
