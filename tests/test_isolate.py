"""`cfsig.isolate.run_limited`: a stage in a forked child, under a time and a memory limit.

The functions run in the child are module-level: the child is forked, so only their results
are pickled. Each writes its process id to a file first, so that the test can check that the
child is gone afterwards.
"""

import os
import signal
import time

import numpy as np
import psutil
import pytest

from cfsig.errors import MeshError, StageLimitError
from cfsig.isolate import Limits, run_limited


def _note_pid(path):
    with open(path, "w") as file:
        file.write(str(os.getpid()))


def _array(pid_file, n):
    _note_pid(pid_file)
    return np.arange(n, dtype=np.float64) * 0.5, {"n": n}


def _sleep(pid_file, seconds):
    _note_pid(pid_file)
    time.sleep(seconds)
    return "woke up"


def _allocate(pid_file, count):
    _note_pid(pid_file)
    return float(np.ones(count).sum())


def _segfault(pid_file):
    _note_pid(pid_file)
    os.kill(os.getpid(), signal.SIGSEGV)
    time.sleep(10)


def _boom(pid_file):
    _note_pid(pid_file)
    raise ValueError("boom")


def _silent_error(pid_file):
    _note_pid(pid_file)
    raise KeyError


def _quit(pid_file):
    _note_pid(pid_file)
    os._exit(0)


def _unpicklable(pid_file):
    _note_pid(pid_file)
    return lambda: None


def _noisy(pid_file):
    _note_pid(pid_file)
    os.write(1, b"child-out-fd1\n")
    os.write(2, b"child-err-fd2\n")
    return "quiet"


@pytest.fixture
def pid_file(tmp_path):
    return tmp_path / "child.pid"


def _assert_gone(pid_file):
    """The child wrote its id, and it is neither running nor a zombie: it was reaped."""
    pid = int(pid_file.read_text())
    assert pid != os.getpid()
    with pytest.raises(ChildProcessError):
        os.waitpid(pid, os.WNOHANG)  # not our child any more: already reaped
    if psutil.pid_exists(pid):  # only a new, unrelated process may have taken the id
        assert psutil.Process(pid).ppid() != os.getpid()


def _address_space_mib():
    """This process's address space: the child is forked with all of it."""
    return psutil.Process().memory_info().vms >> 20


def test_result_comes_back(pid_file):
    n = 2_000_000  # 16 MB, far more than a pipe holds at once
    values, extra = run_limited(_array, (pid_file, n), Limits(seconds=30), "the test stage")
    assert np.array_equal(values, np.arange(n, dtype=np.float64) * 0.5) and extra == {"n": n}
    assert values.dtype == np.float64
    _assert_gone(pid_file)


def test_time_limit(pid_file):
    start = time.monotonic()
    with pytest.raises(StageLimitError, match="the test stage took longer than 0.5 s"):
        run_limited(_sleep, (pid_file, 30), Limits(seconds=0.5), "the test stage")
    assert time.monotonic() - start < 10
    _assert_gone(pid_file)


def test_memory_limit(pid_file):
    cap = _address_space_mib() + 512  # room to run, not for 80 GB
    limits = Limits(seconds=30, memory_mb=cap)
    with pytest.raises(StageLimitError, match=f"the test stage needed more than {cap} MiB"):
        run_limited(_allocate, (pid_file, 10**10), limits, "the test stage")
    _assert_gone(pid_file)
    assert run_limited(_allocate, (pid_file, 10**7), limits, "the test stage") == 1e7  # 80 MB


def test_crash(pid_file):
    with pytest.raises(StageLimitError, match=r"the test stage crashed \(SIGSEGV\)"):
        run_limited(_segfault, (pid_file,), Limits(seconds=30), "the test stage")
    _assert_gone(pid_file)


@pytest.mark.parametrize(
    ("func", "message"),
    [(_boom, "failed: boom"), (_silent_error, "failed: KeyError")],
    ids=["message", "no-message"],
)
def test_exception(pid_file, func, message):
    with pytest.raises(StageLimitError, match=f"the test stage {message}$") as info:
        run_limited(func, (pid_file,), Limits(seconds=30), "the test stage")
    assert isinstance(info.value, MeshError)
    _assert_gone(pid_file)


@pytest.mark.parametrize("func", [_quit, _unpicklable], ids=["exit", "unpicklable"])
def test_no_result(pid_file, func):
    with pytest.raises(StageLimitError, match="the test stage exited without a result"):
        run_limited(func, (pid_file,), Limits(seconds=30), "the test stage")
    _assert_gone(pid_file)


def test_child_output_is_silenced(pid_file, capfd):
    capfd.readouterr()
    assert run_limited(_noisy, (pid_file,), Limits(seconds=30), "the test stage") == "quiet"
    out, err = capfd.readouterr()
    assert "child" not in out and "child" not in err
    _assert_gone(pid_file)


def test_parent_output_is_kept(pid_file, capfd):
    """The redirection is the child's own: the parent still writes to its fd 1 afterwards."""
    run_limited(_noisy, (pid_file,), Limits(seconds=30), "the test stage")
    os.write(1, b"parent-out\n")
    assert "parent-out" in capfd.readouterr().out


def test_crash_does_not_dump_a_traceback(pid_file, capfd):
    with pytest.raises(StageLimitError, match="SIGSEGV"):
        run_limited(_segfault, (pid_file,), Limits(seconds=30), "the test stage")
    out, err = capfd.readouterr()
    assert "Fatal Python error" not in err and "Segmentation fault" not in err
