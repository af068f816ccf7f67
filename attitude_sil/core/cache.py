"""Where the package keeps what it compiles: the laws' dispatch table and numba's machine code.

numba caches a function's machine code beside a stamp of the function's own
source file. A compiled function that inlines helpers from other modules
(the batch loop inlines the plant's lanes and the metrics' rows; a law's step
inlines the control kernels) would keep its stale code after an edit of a
helper. So numba's cache for every process that imports the package lives in
a folder named by a digest of every source file of :mod:`attitude_sil.core`:
an edit anywhere there starts a fresh cache, and an unedited tree finds its
code again. The folder is under :func:`cache_dir`; this sets numba's
``NUMBA_CACHE_DIR`` (which the package thus owns) before the first compiled
function of the package is declared.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import sys
from collections.abc import Iterator
from pathlib import Path

__all__ = ["cache_dir", "core_digest", "numba_cache_dir", "use_numba_cache", "numba_cache_in"]


def cache_dir() -> Path:
    """The package's cache folder: ``$ATTITUDE_SIL_CACHE_DIR``, else ``$XDG_CACHE_HOME/attitude_sil``, else
    ``~/.cache/attitude_sil``."""
    base = os.environ.get("ATTITUDE_SIL_CACHE_DIR")
    if base:
        return Path(base)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "attitude_sil"


def core_digest() -> str:
    """SHA-256 (hex) of every source file of ``attitude_sil.core``, in path order."""
    root = Path(__file__).resolve().parent
    h = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        h.update(path.relative_to(root).as_posix().encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def numba_cache_dir() -> Path:
    """numba's cache folder for this tree of ``attitude_sil.core`` (see the module docstring)."""
    return cache_dir() / "numba" / core_digest()[:16]


def use_numba_cache() -> Path:
    """Point numba's cache at :func:`numba_cache_dir` (numba's config if it is loaded, else its environment)."""
    folder = numba_cache_dir()
    os.environ["NUMBA_CACHE_DIR"] = str(folder)  # read by numba's config when it loads, and by child processes
    config = sys.modules.get("numba.core.config")
    if config is not None:
        config.CACHE_DIR = str(folder)
    return folder


@contextlib.contextmanager
def numba_cache_in(name: str) -> Iterator[Path]:
    """Functions made compiled-and-cached inside this block keep their cache in a sub-folder ``name`` of
    :func:`numba_cache_dir` (numba reads the folder as a function is declared).

    The batch loop is compiled once per set of laws (:mod:`attitude_sil.core.sim.batch`): its signatures
    name the laws' record classes, and numba reads every signature of a cache index at once, so an index
    shared by the law sets would fail in a process that lacks one set's classes (a plugin since removed).
    """
    import numba  # loaded already by the caller, which declares compiled functions

    folder = numba_cache_dir() / name
    before = numba.config.CACHE_DIR
    numba.config.CACHE_DIR = str(folder)
    try:
        yield folder
    finally:
        numba.config.CACHE_DIR = before
