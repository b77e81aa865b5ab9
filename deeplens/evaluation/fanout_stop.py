"""Stopping a fanned-out evaluation: its jobs stop with it, however it ends.

``deeplens eval eval.launcher=joblib`` (:mod:`.fanout`) starts a Hydra multirun whose joblib
(loky) workers train one variant x seed each.  SIGTERM or Ctrl-C to the evaluation is forwarded
to that process tree (:func:`run_process_tree`), but ``kill -9`` cannot be caught: the
workers would go on training and writing checkpoints into the folder, beside a rerun.  So the
evaluation names itself in the environment of the multirun (:data:`PARENT_ENV`: its pid, its
start time as the kernel records it, and the host) and every job starts :func:`watch_parent`:
a daemon thread that checks every :data:`POLL_S` seconds whether that process still exists (a
zombie, or another process that reused the pid, counts as gone) and, when not, ends the job's
process at once (``os._exit``, status :data:`ORPHAN_STATUS`): no further checkpoint is written
(checkpoints are written atomically, so the last one is whole).
"""

from __future__ import annotations

import ctypes
import os
import signal
import socket
import subprocess
import sys
import threading
import time

from ..training.stop_signals import StoppedBySignal

__all__ = ["ORPHAN_STATUS", "PARENT_ENV", "POLL_S", "STOP_GRACE_S", "parent_alive",
           "parent_token", "process_start", "run_process_tree", "watch_parent"]

#: environment variable naming the evaluation a job belongs to: ``<pid>:<start>:<host>``
PARENT_ENV = "DEEPLENS_FANOUT_PARENT"
#: seconds between two checks of the parent
POLL_S = 0.5
#: exit status of a job whose evaluation is gone (128 + SIGHUP, "the controlling process left")
ORPHAN_STATUS = 129
#: seconds the jobs get to stop after SIGTERM before they are killed
STOP_GRACE_S = 10.0
_THREAD_NAME = "deeplens-parent-watch"


def process_start(pid: int) -> str | None:
    """The start time of process ``pid`` (``/proc/<pid>/stat`` field 22, clock ticks since
    boot) as text; ``""`` where ``/proc`` is not available; ``None`` when the process does not
    exist or is a zombie (it has exited; its parent has not reaped it yet)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            stat = f.read()
    except FileNotFoundError:
        return None if os.path.isdir("/proc/self") else _exists_without_proc(pid)
    except OSError:
        return _exists_without_proc(pid)
    fields = stat[stat.rfind(")") + 2:].split()   # after "pid (comm) ": state is field 3
    if not fields or fields[0] in ("Z", "X"):
        return None
    return fields[19] if len(fields) > 19 else ""


def _exists_without_proc(pid: int) -> str | None:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return None
    except PermissionError:   # exists, another user's
        return ""
    return ""


def parent_token(pid: int | None = None) -> str:
    """The :data:`PARENT_ENV` value naming process ``pid`` (default: this one)."""
    pid = os.getpid() if pid is None else pid
    return f"{pid}:{process_start(pid) or ''}:{socket.gethostname()}"


def parent_alive(token: str) -> bool:
    """Whether the process a :data:`PARENT_ENV` value names still runs (``True`` for a value
    that cannot be read, or one from another host: nothing to watch there)."""
    pid, _, rest = token.partition(":")
    start, _, host = rest.partition(":")
    if not pid.isdigit() or (host and host != socket.gethostname()):
        return True
    now = process_start(int(pid))
    return now is not None and (not start or not now or now == start)


def watch_parent(token: str | None = None, poll_s: float = POLL_S) -> threading.Thread | None:
    """Start the watchdog thread for the evaluation ``token`` names (default: the
    :data:`PARENT_ENV` of this process; nothing when it is unset).  At most one per process
    (a worker that runs several jobs keeps the first).  Returns the thread, or ``None``."""
    token = os.environ.get(PARENT_ENV) if token is None else token
    if not token:
        return None
    for t in threading.enumerate():
        if t.name == _THREAD_NAME:
            return t

    def watch():
        while parent_alive(token):
            time.sleep(poll_s)
        pid = token.split(":", 1)[0]
        print(f"deeplens eval job (pid {os.getpid()}): the evaluation that started it (pid "
              f"{pid}) is gone; stopping without writing further", file=sys.stderr, flush=True)
        os._exit(ORPHAN_STATUS)

    t = threading.Thread(target=watch, name=_THREAD_NAME, daemon=True)
    t.start()
    return t


def _die_with_parent():
    """A ``preexec_fn`` for the child: SIGTERM to it when this process dies, even by
    ``kill -9`` (Linux ``prctl(PR_SET_PDEATHSIG)``; ``None`` elsewhere, where the jobs' own
    watchdog, :func:`watch_parent`, stops them).  ``prctl`` is looked up here, before the fork,
    so that the child only calls it."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    return lambda: prctl(1, signal.SIGTERM, 0, 0, 0)   # 1 = PR_SET_PDEATHSIG


def _signal_group(pgid: int, signum: int) -> bool:
    """Send ``signum`` to the process group ``pgid``; ``False`` when none of it is left."""
    try:
        os.killpg(pgid, signum)
    except ProcessLookupError:
        return False
    except PermissionError:   # only zombies or others' processes left
        return True
    return True


def run_process_tree(cmd: list[str], env=None, grace_s: float = STOP_GRACE_S,
                     poll_s: float = 0.2) -> int:
    """Run ``cmd`` as the leader of its own process group (a new session) and return its exit
    status.  SIGTERM, SIGINT or SIGHUP to this process (in the main thread) stop the whole group,
    the command and every process it started (the joblib workers): SIGTERM to the group, then
    SIGKILL to what is left after ``grace_s`` seconds; then :class:`~deeplens.training.stop_signals.StoppedBySignal`
    (status ``128 + signal``) is raised.  The command also gets SIGTERM when this process dies
    by ``kill -9`` (:func:`_die_with_parent`)."""
    received: list[int] = []
    proc = subprocess.Popen(cmd, env=env, start_new_session=True,
                            preexec_fn=_die_with_parent())
    pgid = proc.pid   # the leader of a new session: its group id is its pid

    def handler(signum, frame):
        if not received:
            received.append(signum)
            _signal_group(pgid, signal.SIGTERM)

    old = {}
    if threading.current_thread() is threading.main_thread():
        for s_ in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
            old[s_] = signal.getsignal(s_)
            signal.signal(s_, handler)
    deadline = None
    try:
        while True:
            try:
                rc = proc.wait(timeout=poll_s)
            except subprocess.TimeoutExpired:
                rc = None
            if received and deadline is None:
                deadline = time.monotonic() + grace_s
            if deadline is not None and time.monotonic() > deadline:
                _signal_group(pgid, signal.SIGKILL)
            if rc is not None:
                break
        if received:   # the workers outlive the leader: wait for them, then kill what is left
            while _signal_group(pgid, 0) and time.monotonic() < deadline:
                time.sleep(poll_s)
            _signal_group(pgid, signal.SIGKILL)
    finally:
        for s_, h in old.items():
            signal.signal(s_, h)
    if received:
        name = signal.Signals(received[0]).name
        msg = (f"deeplens eval: stopped by {name}; the fanned-out jobs were stopped (runs that "
               f"finished are reused when the evaluation is started again in the same folder)")
        print(msg, file=sys.stderr, flush=True)
        raise StoppedBySignal(msg, received[0], None)
    return rc
