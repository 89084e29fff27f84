"""Finding the rigslim installation and running the worker (worker.py) in it, out of process.

The Python that runs rigslim is, in order: the add-on preference "rigslim
Python"; the environment variable ``RIGSLIM_PYTHON``; the interpreter of a
``rigslim`` command on ``PATH`` (its ``#!`` line). Whatever fails gives one
:class:`RunnerError` line saying what was tried and how to fix it.

:class:`Job` runs ``PYTHON worker.py COMMAND REQUEST RESULT`` without
blocking: a thread reads the worker's JSON lines, :meth:`Job.poll` returns the
latest progress, and :meth:`Job.cancel` ends the process.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

WORKER = Path(__file__).with_name("worker.py")
PROTOCOL = 1


class RunnerError(Exception):
    """A one-line problem running rigslim (shown in Blender's status bar and Info editor)."""


def interpreter_of_script(path: str) -> str | None:
    """The interpreter named by a console script's ``#!`` line (None if it has none)."""
    try:
        with open(path, "rb") as fh:
            first = fh.readline(4096).decode("utf-8", "replace").strip()
    except OSError:
        return None
    if not first.startswith("#!"):
        return None
    parts = first[2:].split()
    if parts and os.path.basename(parts[0]) == "env" and len(parts) > 1:
        return shutil.which(parts[1])
    return parts[0] if parts else None


def find_python(preference: str = "") -> tuple[str, str]:
    """The Python to run rigslim with, and where that choice came from.

    Raises
    ------
    RunnerError
        Nothing configured or found, or the configured path is not a program.
    """
    tried = []
    if preference.strip():
        path = os.path.abspath(os.path.expanduser(preference.strip()))
        if os.path.isdir(path):
            for cand in ("bin/python", "bin/python3", "Scripts/python.exe", "python.exe"):
                if os.path.isfile(os.path.join(path, cand)):
                    return os.path.join(path, cand), "preferences"
        if not (os.path.isfile(path) and os.access(path, os.X_OK)):
            raise RunnerError(f"rigslim Python '{path}' (add-on preferences) is not a program; choose the python "
                              "of an environment where 'pip install rigslim' was run (e.g. .venv/bin/python)")
        script_python = interpreter_of_script(path) if os.path.basename(path).startswith("rigslim") else None
        return script_python or path, "preferences"
    tried.append("the add-on preference 'rigslim Python' (empty)")
    env = os.environ.get("RIGSLIM_PYTHON", "").strip()
    if env:
        if not (os.path.isfile(env) and os.access(env, os.X_OK)):
            raise RunnerError(f"RIGSLIM_PYTHON='{env}' is not a program; set it to the python that has rigslim")
        return env, "RIGSLIM_PYTHON"
    tried.append("RIGSLIM_PYTHON (unset)")
    script = shutil.which("rigslim")
    if script:
        py = interpreter_of_script(script)
        if py and os.path.isfile(py):
            return py, f"the rigslim command ({script})"
        tried.append(f"{script} (no #! line naming a Python)")
    else:
        tried.append("a rigslim command on PATH (none)")
    raise RunnerError("rigslim is not installed or not configured: tried " + "; ".join(tried)
                      + ". Install it (pip install rigslim) and set Edit > Preferences > Add-ons > rigslim > "
                      "rigslim Python to that environment's python")


def _lines_to_error(lines: list[str], stderr: str, rc: int, python: str) -> str:
    for line in reversed(lines):
        try:
            obj = json.loads(line)
        except ValueError:
            continue
        if isinstance(obj, dict) and "error" in obj:
            return str(obj["error"])
    tail = [s for s in stderr.strip().splitlines() if s.strip()]
    last = tail[-1] if tail else "no message"
    return f"rigslim worker ({python}) failed with exit code {rc}: {last}"


def check(python: str, timeout: float = 120.0) -> dict:
    """Run ``worker.py version``: rigslim's version, its defaults and the decimator's parameters.

    Raises
    ------
    RunnerError
        The Python does not start, cannot import rigslim, or speaks another protocol.
    """
    try:
        proc = subprocess.run([python, str(WORKER), "version"], capture_output=True, text=True, timeout=timeout,
                              env=_worker_env())
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise RunnerError(f"could not run rigslim Python '{python}': {exc}") from None
    lines = proc.stdout.splitlines()
    if proc.returncode != 0:
        raise RunnerError(_lines_to_error(lines, proc.stderr, proc.returncode, python))
    for line in lines:
        try:
            obj = json.loads(line)
        except ValueError:
            continue
        if "version" in obj:
            if obj.get("protocol") != PROTOCOL:
                raise RunnerError(f"the rigslim worker speaks protocol {obj.get('protocol')}, this add-on {PROTOCOL}")
            return obj
    raise RunnerError(f"rigslim Python '{python}' printed no version: {proc.stdout.strip()[:200]}")


def _worker_env() -> dict[str, str]:
    env = dict(os.environ)
    # Blender's own Python settings must not leak into another interpreter.
    for key in ("PYTHONHOME", "PYTHONPATH", "PYTHONSTARTUP", "PYTHONEXECUTABLE"):
        env.pop(key, None)
    env["PYTHONUNBUFFERED"] = "1"
    env["PYTHONIOENCODING"] = "utf-8"
    return env


@dataclass
class Job:
    """One worker run: ``PYTHON worker.py COMMAND REQUEST.npz RESULT.npz`` in a temporary folder."""

    python: str
    command: str
    request: dict
    folder: str = field(default_factory=lambda: tempfile.mkdtemp(prefix="rigslim-blender-"))
    fraction: float = 0.0
    message: str = "starting rigslim"
    lines: list[str] = field(default_factory=list)
    started: float = field(default_factory=time.monotonic)
    _proc: subprocess.Popen | None = None
    _stderr: list[str] = field(default_factory=list)
    _threads: list[threading.Thread] = field(default_factory=list)

    @property
    def request_path(self) -> str:
        return os.path.join(self.folder, "request.npz")

    @property
    def result_path(self) -> str:
        return os.path.join(self.folder, "result.npz")

    def start(self) -> Job:
        np.savez(self.request_path, protocol=np.int64(PROTOCOL), **self.request)
        try:
            self._proc = subprocess.Popen([self.python, str(WORKER), self.command, self.request_path,
                                           self.result_path], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                          text=True, env=_worker_env(), bufsize=1)
        except OSError as exc:
            self.cleanup()
            raise RunnerError(f"could not run rigslim Python '{self.python}': {exc}") from None
        self._threads = [threading.Thread(target=self._read_stdout, daemon=True),
                         threading.Thread(target=self._read_stderr, daemon=True)]
        for t in self._threads:
            t.start()
        return self

    def _read_stdout(self) -> None:
        assert self._proc is not None and self._proc.stdout is not None
        for line in self._proc.stdout:
            self.lines.append(line)
            try:
                obj = json.loads(line)
            except ValueError:
                continue
            if isinstance(obj, dict) and "progress" in obj:
                self.fraction, self.message = float(obj["progress"]), str(obj.get("message", ""))

    def _read_stderr(self) -> None:
        assert self._proc is not None and self._proc.stderr is not None
        for line in self._proc.stderr:
            self._stderr.append(line)

    def poll(self) -> bool:
        """True once the worker has exited."""
        return self._proc is not None and self._proc.poll() is not None

    def elapsed(self) -> float:
        return time.monotonic() - self.started

    def result(self) -> dict[str, np.ndarray]:
        """The worker's result arrays (waits for it to exit).

        Raises
        ------
        RunnerError
            The worker reported an error or wrote no result.
        """
        assert self._proc is not None
        rc = self._proc.wait()
        for t in self._threads:
            t.join(timeout=5)
        try:
            if rc != 0 or not os.path.isfile(self.result_path):
                raise RunnerError(_lines_to_error(self.lines, "".join(self._stderr), rc, self.python))
            with np.load(self.result_path, allow_pickle=False) as z:
                return {k: z[k] for k in z.files}
        finally:
            self.cleanup()

    def cancel(self) -> None:
        if self._proc is not None and self._proc.poll() is None:
            self._proc.kill()
            self._proc.wait()
        self.cleanup()

    def cleanup(self) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)
