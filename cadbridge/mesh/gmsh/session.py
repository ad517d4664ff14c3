"""One gmsh call's ownership of the process-wide gmsh: `GmshSession` initialises gmsh (or adds
a private model when the caller holds it), records every option it changes and restores all
on exit; `quiet_stdout` silences C++ code that prints to file descriptor 1."""

from __future__ import annotations

import threading

__all__ = ["GmshSession", "apply_options", "quiet_stdout"]

_LOCK = threading.RLock()  # gmsh is a process-wide singleton


class GmshSession:
    """Context manager owning gmsh for one call: initialise (or add a private model if the
    caller holds gmsh already), track changed options, and undo everything on exit."""

    def __init__(self, verbose: bool = False) -> None:
        self.verbose = verbose
        self._owner = False
        self._saved_num: dict[str, float] = {}
        self._saved_str: dict[str, str] = {}
        self._model = "cadbridge-mesh"
        self._prev_model: str | None = None
        self.views: list[int] = []  # post-processing views made in the call (not part of the model)

    def __enter__(self):
        import gmsh

        _LOCK.acquire()
        try:
            if gmsh.isInitialized():
                self._prev_model = gmsh.model.getCurrent()
                if self._prev_model.startswith(self._model):  # nested in another call: a name of its own
                    self._model = f"{self._prev_model}-nested"
            else:
                gmsh.initialize(readConfigFiles=False, interruptible=False)
                self._owner = True
                _restore_python_signals()
            # in a watched child, gmsh's Info lines (one per curve and surface) go to the parent
            # (`cadbridge.mesh.gmsh.isolated`), which passes them on only where verbose
            from cadbridge.mesh.gmsh.isolated import in_child

            watched = in_child()
            self.set("General.Terminal", 1 if self.verbose or watched else 0)
            self.set("General.Verbosity", 5 if self.verbose else 4 if watched else 1)
            gmsh.model.add(self._model)
        except BaseException:
            self._cleanup()
            raise
        return self

    @property
    def gmsh(self):
        import gmsh

        return gmsh

    def set(self, name: str, value: float | str) -> None:
        """Set a gmsh option, remembering its old value (restored on exit)."""
        import gmsh

        if isinstance(value, str):
            if name not in self._saved_str and not self._owner:
                self._saved_str[name] = gmsh.option.getString(name)
            gmsh.option.setString(name, value)
        else:
            if name not in self._saved_num and not self._owner:
                self._saved_num[name] = gmsh.option.getNumber(name)
            gmsh.option.setNumber(name, float(value))

    def _cleanup(self) -> None:
        import gmsh

        try:
            if self._owner:
                if gmsh.isInitialized():
                    gmsh.finalize()
            elif gmsh.isInitialized():
                for v in self.views:
                    try:
                        gmsh.view.remove(v)
                    except Exception:
                        pass
                try:
                    gmsh.model.setCurrent(self._model)
                    gmsh.model.remove()
                except Exception:
                    pass
                for k, v in self._saved_num.items():
                    gmsh.option.setNumber(k, v)
                for k, v in self._saved_str.items():
                    gmsh.option.setString(k, v)
                if self._prev_model:
                    try:
                        gmsh.model.setCurrent(self._prev_model)
                    except Exception:
                        pass
        finally:
            _restore_python_signals()
            _LOCK.release()

    def __exit__(self, *exc) -> None:
        self._cleanup()


def _restore_python_signals() -> None:
    """Give SIGPIPE and SIGINT back the handlers Python keeps for them.

    gmsh resets SIGPIPE to its default (terminate) at the C level: afterwards a write to a
    closed pipe (e.g. to a crashed worker process) would kill the whole process instead of
    raising BrokenPipeError. Python's bookkeeping still holds the intended handlers.
    """
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        return  # signal handlers can only be set from the main thread
    for sig in (signal.SIGPIPE, signal.SIGINT):
        handler = signal.getsignal(sig)
        if handler is not None:
            signal.signal(sig, handler)


class quiet_stdout:
    """Redirect file descriptor 1 to /dev/null (C++ code printing to std::cout)."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled
        self._saved: int | None = None

    def __enter__(self) -> None:
        import os
        import sys

        if not self.enabled:
            return
        try:
            sys.stdout.flush()
            self._saved = os.dup(1)
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, 1)
            os.close(devnull)
        except OSError:
            self._saved = None

    def __exit__(self, *exc) -> None:
        import os

        if self._saved is not None:
            os.dup2(self._saved, 1)
            os.close(self._saved)


def apply_options(sess: GmshSession, opts: dict[str, float | str]) -> None:
    """``sess.set`` for every option of ``opts``."""
    for k, v in opts.items():
        sess.set(k, v)
