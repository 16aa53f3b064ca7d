"""Running a third-party stage in a child process, under a time and a memory limit.

A stage that can hang (a volumetric remesh stuck on a degenerate input) or blow up memory (a
grid far finer than the input needs) must cost only its own mesh. The child is forked from the
calling process, so it starts at once with every module the caller has imported; its address
space is capped with ``RLIMIT_AS`` and it is killed when the time runs out. POSIX only.
"""

from __future__ import annotations

import faulthandler
import os
import pickle
import resource
import select
import signal
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from cfsig.errors import StageLimitError


@dataclass(frozen=True)
class Limits:
    """Limits of one isolated stage.

    Attributes
    ----------
    seconds : float
        Wall time allowed, from the fork to the result.
    memory_mb : int
        Address space allowed to the child, in MiB (its imported libraries included).
    """

    seconds: float = 30.0
    memory_mb: int = 4096


def run_limited(func: Callable[..., Any], args: tuple, limits: Limits, what: str) -> Any:
    """Call ``func(*args)`` in a forked child process and return its result.

    The child's standard output and error go to ``/dev/null`` (native libraries print there
    directly). Exceptions raised in the child come back as `StageLimitError` with their message.

    Parameters
    ----------
    func : callable
        The stage; its result must pickle.
    args : tuple
        Its arguments.
    limits : Limits
        Time and memory allowed.
    what : str
        The stage's name, for messages.

    Returns
    -------
    result
        What ``func`` returned.

    Raises
    ------
    StageLimitError
        The child ran out of time or memory, died, or raised.
    """
    read_end, write_end = os.pipe()
    with warnings.catch_warnings():  # Python 3.12+ warns about fork in threaded processes
        warnings.simplefilter("ignore", DeprecationWarning)
        pid = os.fork()
    if pid == 0:
        os.close(read_end)
        _child(func, args, limits, write_end)
    os.close(write_end)
    try:
        data = _read_until(read_end, time.monotonic() + limits.seconds)
    finally:
        os.close(read_end)
    if data is None:
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
        raise StageLimitError(f"{what} took longer than {limits.seconds:g} s")
    _, status = os.waitpid(pid, 0)
    if not data:
        if os.WIFSIGNALED(status):
            name = signal.Signals(os.WTERMSIG(status)).name
            raise StageLimitError(f"{what} crashed ({name})")
        code = os.WEXITSTATUS(status)  # 0: the result would not pickle; else native code quit
        detail = "" if code == 0 else f" (status {code}: out of memory in native code?)"
        raise StageLimitError(f"{what} exited without a result{detail}")
    kind, value = pickle.loads(data)
    if kind == "memory":
        raise StageLimitError(f"{what} needed more than {limits.memory_mb} MiB")
    if kind == "error":
        raise StageLimitError(f"{what} failed: {value}")
    return value


def _child(func: Callable[..., Any], args: tuple, limits: Limits, write_end: int) -> None:
    """In the child: limit memory, silence output, run, send the pickled outcome, exit."""
    try:
        faulthandler.disable()  # a crash is reported by the parent, not dumped by the child
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        cap = limits.memory_mb << 20
        resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
        try:
            outcome: tuple[str, Any] = ("ok", func(*args))
        except MemoryError:
            outcome = ("memory", None)
        except Exception as exc:  # any failure of the stage is reported, whatever its type
            outcome = ("error", str(exc) or type(exc).__name__)
        data = pickle.dumps(outcome, protocol=pickle.HIGHEST_PROTOCOL)
        with os.fdopen(write_end, "wb") as pipe:
            pipe.write(data)
    finally:
        os._exit(0)


def _read_until(fd: int, deadline: float) -> bytes | None:
    """Everything written to a pipe until its writer closes it, or None at the deadline."""
    chunks: list[bytes] = []
    while True:
        left = deadline - time.monotonic()
        if left <= 0 or not select.select([fd], [], [], left)[0]:
            return None
        chunk = os.read(fd, 1 << 20)
        if not chunk:
            return b"".join(chunks)
        chunks.append(chunk)
