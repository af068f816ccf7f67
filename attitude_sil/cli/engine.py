"""``attitude-sil engine``: where the compiled batch engine's code is, and the one part of it that is generated.

The loop is :mod:`attitude_sil.core.sim.batch_loop` and the laws' loops are
:mod:`attitude_sil.core.control.dispatch`, both files of the package; only
the dispatch table that binds each installed law's step to those loops is
generated (:func:`attitude_sil.core.control.compiled.dispatch_source`).
``--source`` prints that table.
"""

from __future__ import annotations

import argparse


def add(sub: argparse._SubParsersAction) -> None:
    """Add the verb's parser to ``sub`` (cheap: the verb's imports wait for :func:`execute`)."""
    eng = sub.add_parser("engine", help="the compiled engine's files, laws and caches; --source: the generated "
                         "dispatch table")
    eng.add_argument("--source", action="store_true",
                     help="print the generated dispatch table (the one generated module) and nothing else")
    eng.set_defaults(func=execute)


def execute(args: argparse.Namespace) -> int:
    """Run the verb; returns the exit code."""
    import inspect

    from attitude_sil.core.cache import numba_cache_dir
    from attitude_sil.core.control import compiled, dispatch, registry
    from attitude_sil.core.sim import batch_loop

    laws = [registry.get(name) for name in registry.names()]
    if args.source:
        print(compiled.dispatch_source(laws), end="")
        return 0
    table = registry.dispatch_module()
    print(f"batch loop:     {inspect.getsourcefile(batch_loop)}")
    print(f"laws' loops:    {inspect.getsourcefile(dispatch)}")
    print(f"dispatch table: {table.__file__} (generated; attitude-sil engine --source)")
    print(f"numba cache:    {numba_cache_dir()}")
    print("laws (code, name, module):")
    for code, law in enumerate(laws):
        print(f"  {code}  {law.name:<12} {law.step.py_func.__module__}")
    return 0
