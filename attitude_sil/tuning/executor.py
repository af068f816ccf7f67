"""Where batch evaluations run: one small interface, three back-ends.

Every batch evaluation (tuning populations, robust-design costs, Monte Carlo
campaigns) is cut into chunks of episodes, and each chunk is one call
``fn(*args)`` that runs its episodes in the batch engine and returns their
results. An :class:`Executor` runs such calls:

* :class:`InProcess` — one after another in this process (the engine's threads
  use every core);
* :class:`LocalProcesses` — a pool of forked worker processes on this machine,
  one engine thread each (the default, as before);
* :class:`DaskCluster` — the workers of a Dask distributed scheduler
  (``dask scheduler`` / ``dask worker`` on any number of machines, or a
  :class:`distributed.LocalCluster`), one engine thread per task. Dask re-runs
  the tasks of a worker that dies. ``tls://`` addresses use Dask's security
  configuration (``distributed.comm.tls.*``: CA, client certificate and key).
  A scheduler lost mid-run is one :class:`~attitude_sil.errors.SchedulerLostError`
  naming its address, never distributed's own traceback.

Chunks carry their own seeds and episode indices (noise seed = base seed +
global episode index, dispersions drawn per run index), so a result is the same
bit for bit whichever back-end ran it and however the work was cut.
"""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import multiprocessing as mp
import os
import sys
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from typing import Any
from urllib.parse import urlsplit

from attitude_sil.errors import AttitudeSilError, SchedulerLostError

__all__ = ["Executor", "InProcess", "LocalProcesses", "DaskCluster", "make_executor", "check_scheduler_address",
           "SCHEDULER_ENV"]

#: the environment variable Dask itself reads for a scheduler address
SCHEDULER_ENV = "DASK_SCHEDULER_ADDRESS"


class Executor:
    """Runs chunk calls ``fn(*args)``; a context manager.

    Attributes
    ----------
    name : str
        ``in-process``, ``processes`` or ``dask``.
    workers : int
        How many calls run at once (a hint for cutting work into chunks).
    threads : int or None
        The engine threads each call should use (None: every core).
    """

    name = "executor"
    workers = 1
    threads: int | None = None

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Release workers (nothing for the in-process back-end)."""

    def as_completed(self, fn: Callable, calls: Sequence[tuple],
                     should_stop: Callable[[], bool] | None = None) -> Iterator[tuple[int, Any]]:
        """Yield ``(i, fn(*calls[i]))`` as the calls finish (any order); stop early when ``should_stop()``.

        The calls not started when the iteration stops are cancelled.
        """
        for i, args in enumerate(calls):
            if should_stop is not None and should_stop():
                return
            yield i, fn(*args)

    def map(self, fn: Callable, calls: Sequence[tuple]) -> list:
        """``[fn(*c) for c in calls]``, run by the back-end, in order."""
        out: list = [None] * len(calls)
        for i, r in self.as_completed(fn, calls):
            out[i] = r
        return out


class InProcess(Executor):
    """Every call in this process, one after another; the engine uses every core."""

    name = "in-process"


class LocalProcesses(Executor):
    """A pool of ``workers`` forked processes on this machine, one engine thread each."""

    name = "processes"
    threads = 1

    def __init__(self, workers: int) -> None:
        self.workers = max(1, int(workers))
        self.pool = ProcessPoolExecutor(self.workers, mp_context=mp.get_context("fork"))

    def close(self) -> None:
        self.pool.shutdown(cancel_futures=True)

    def as_completed(self, fn, calls, should_stop=None):
        futures = {self.pool.submit(fn, *args): i for i, args in enumerate(calls)}
        try:
            pending = set(futures)
            while pending:
                done, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
                for f in done:
                    yield futures[f], f.result()
                if should_stop is not None and should_stop():
                    return
        finally:
            for f in futures:
                f.cancel()


def check_scheduler_address(address: str) -> str:
    """A Dask scheduler address ``tcp://HOST:PORT`` or ``tls://HOST:PORT``, checked; returns it.

    Raises
    ------
    AttitudeSilError
        Not a tcp:// or tls:// address with a host and a port.
    """
    parts = urlsplit(address)
    try:
        port = parts.port
    except ValueError:
        port = None
    if parts.scheme not in ("tcp", "tls") or not parts.hostname or port is None:
        raise AttitudeSilError(f"--scheduler must be tcp://HOST:PORT or tls://HOST:PORT (a Dask scheduler), "
                               f"got {address!r}")
    return address


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


#: how the connection went when no socket error says it
CONNECTION_CLOSED = "its connection closed"


def _cause_name(exc: BaseException) -> str:
    """The socket's own error class (e.g. ``ConnectionResetError``), else :data:`CONNECTION_CLOSED`.

    distributed wraps a reset connection in its CommClosedError, from tornado's StreamClosedError, which keeps
    the socket's error as ``real_error`` (None when the peer closed the stream in order).
    """
    while True:
        inner = exc.__cause__ or getattr(exc, "real_error", None)
        if not isinstance(inner, BaseException):
            break
        exc = inner
    name = type(exc).__name__
    return CONNECTION_CLOSED if name in ("CommClosedError", "StreamClosedError") else name


@contextlib.contextmanager
def _quiet_client_logs() -> Iterator[None]:
    """Mute distributed's client loggers: closing a client that lost its scheduler logs its reconnection's end
    (a traceback, or 'Failed to reconnect') though the error that matters has been said."""
    loggers = [logging.getLogger(name) for name in ("distributed.client", "distributed.utils")]
    before = [lg.disabled for lg in loggers]
    for lg in loggers:
        lg.disabled = True
    try:
        yield
    finally:
        for lg, was in zip(loggers, before, strict=True):
            lg.disabled = was


class DaskCluster(Executor):
    """The workers of a Dask distributed scheduler (or of a :class:`distributed.LocalCluster` given as ``client``).

    Parameters
    ----------
    address : str, optional
        ``tcp://HOST:PORT`` or ``tls://HOST:PORT``; ``tls://`` takes Dask's
        security configuration (``distributed.comm.tls.ca-file``,
        ``distributed.comm.tls.client.cert``, ``.key``). A ``tcp://`` address
        off this machine works but is neither encrypted nor authenticated: a
        warning says so.
    client : distributed.Client, optional
        An existing client (e.g. of a ``LocalCluster``) instead of ``address``.
    timeout : float
        Seconds to wait for the scheduler and for its first worker.
    """

    name = "dask"
    threads = 1

    def __init__(self, address: str | None = None, client=None, timeout: float = 30.0) -> None:
        from distributed import Client  # Dask is imported only where a cluster is used

        self.own = client is None
        if client is None:
            check_scheduler_address(address)
            parts = urlsplit(address)
            if parts.scheme == "tcp" and not _is_loopback(parts.hostname):
                print(f"attitude-sil: warning: {address} is unencrypted and unauthenticated; use tls:// with a Dask "
                      "security configuration off a trusted network", file=sys.stderr)
            # a comm that closes under the client logs it at INFO with a traceback (distributed.batched), often
            # before the loss is seen: the run says it in one line (SchedulerLostError) instead
            logging.getLogger("distributed.batched").setLevel(logging.WARNING)
            try:
                client = Client(address, timeout=timeout, set_as_default=False)
            except (OSError, TimeoutError) as exc:
                raise AttitudeSilError(f"cannot reach the Dask scheduler at {address}: {exc}") from None
        self.client = client
        self.address = client.scheduler.address if address is None else address
        self.lost = False
        try:
            self.client.wait_for_workers(1, timeout=timeout)
        except TimeoutError:
            self.close()
            raise AttitudeSilError(f"the Dask scheduler at {client.scheduler.address} has no workers "
                                   f"(waited {timeout:g} s)") from None
        self.workers = max(1, sum(self.client.nthreads().values()))

    def close(self) -> None:
        if self.own and self.client is not None:
            if self.lost or self.client.status != "running":
                # the client is still trying to reconnect: closing ends that at once, without its logs
                with _quiet_client_logs():
                    self.client.close(timeout=5)
            else:
                self.client.close()
        self.client = None

    def _lost_error(self, exc: BaseException, future=None) -> SchedulerLostError | None:
        """The error to raise for ``exc`` if it means the scheduler is lost, else None (a task's own error).

        A task that raised is its own error whatever the scheduler's state (its future's status is
        ``error``). Otherwise the scheduler is lost when the client cancelled the futures because its
        connection closed, when the client no longer runs (it is reconnecting or gave up), or when a
        connection error met the scheduler (fetching a finished result goes through it).
        """
        from distributed.client import FutureCancelledError

        if future is not None and future.status == "error":
            return None
        cancelled = isinstance(exc, FutureCancelledError) and exc.reason == "scheduler-connection-lost"
        if not (cancelled or isinstance(exc, OSError) or self.client.status != "running"):
            return None
        return self._lost(_cause_name(exc) if isinstance(exc, OSError) else CONNECTION_CLOSED)

    def _lost(self, how: str) -> SchedulerLostError:
        """The one-line error for a lost scheduler; the client is closed without waiting for it from then on."""
        self.lost = True
        return SchedulerLostError(f"lost the Dask scheduler at {self.address} ({how})", self.address)

    def as_completed(self, fn, calls, should_stop=None):
        from distributed import as_completed

        if self.client.status != "running":  # lost between two calls (a tuner's generations)
            raise self._lost(CONNECTION_CLOSED)
        # pure=False: identical calls are still separate tasks. A task whose worker dies is re-run on another
        # by the scheduler (distributed.scheduler.allowed-failures); one that raises is not retried.
        futures = [self.client.submit(fn, *args, pure=False) for args in calls]
        index = {f.key: i for i, f in enumerate(futures)}
        finished = as_completed(futures, loop=self.client.loop)
        try:
            while True:
                f = None
                try:
                    f = next(finished)
                    result = f.result()
                except StopIteration:
                    return
                except Exception as exc:  # a task's own error, or distributed's on a lost connection
                    lost = self._lost_error(exc, f)
                    if lost is None:
                        raise
                    raise lost from None
                yield index[f.key], result
                if should_stop is not None and should_stop():
                    return
        finally:
            if not self.lost:
                self.client.cancel([f for f in futures if not f.done()])


def make_executor(scheduler: str | None = None, workers: int = 1, in_process: bool = False) -> Executor:
    """The back-end a command asks for.

    ``scheduler`` (or ``$DASK_SCHEDULER_ADDRESS``) -> :class:`DaskCluster`; else
    ``workers > 1`` -> :class:`LocalProcesses`; else :class:`InProcess`
    (``in_process`` forces it).
    """
    address = scheduler or os.environ.get(SCHEDULER_ENV) or None
    if address and not in_process:
        return DaskCluster(address)
    if workers > 1 and not in_process:
        return LocalProcesses(workers)
    return InProcess()
