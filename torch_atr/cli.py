"""What every entry point shares (``train.py``, ``track.py``, ``python -m torch_atr...``).

:func:`run_main` runs an entry point's ``main(argv)`` and turns a user error (a bad config,
file, spec or checkpoint; an output that may not be replaced) into one line on stderr,
``PROG: error: MESSAGE``, and exit status 2, the way ``argparse`` reports a bad argument. Other
exceptions are bugs and keep their traceback; :class:`ArgumentParser` reports a bad flag the same
way. :func:`console_logging` sets up their log lines,
which never land inside a progress bar. :func:`in_repo` finds the repository's defaults
(``checkpoints/default.pt``) from any folder.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from pathlib import Path
from typing import Callable, NoReturn

from tqdm import tqdm

# ValueError covers ConfigError and InputError; OSError covers missing files, outputs that may
# not be replaced (OutputExistsError) and permissions.
USER_ERRORS: tuple[type[BaseException], ...] = (ValueError, OSError)
REPO = Path(__file__).resolve().parents[1]  # a source checkout's root: checkpoints/, configs/


def in_repo(path: str | Path) -> Path:
    """A relative ``path`` as given if it exists from here, else from the repository root when it
    exists there (the defaults, run from another folder); an absolute one as given."""
    p = Path(path)
    return p if p.is_absolute() or p.exists() or not (REPO / p).exists() else REPO / p


def error_text(exc: BaseException) -> str:
    """``exc``'s message on one line. An OSError's leaves out Python's ``[Errno N]`` prefix: its reason,
    after the file(s) it names the way a shell tool puts it (``runs/x/metrics.json: Permission
    denied``; ``a -> b: Invalid cross-device link``)."""
    if isinstance(exc, OSError) and exc.errno is not None and exc.strerror:
        files = [os.fsdecode(f) if isinstance(f, (bytes, os.PathLike)) else str(f)
                 for f in (exc.filename, exc.filename2) if f is not None]
        text = f"{' -> '.join(files)}: {exc.strerror}" if files else exc.strerror
    else:
        text = str(exc)
    return " ".join(text.split()) or type(exc).__name__


class ArgumentParser(argparse.ArgumentParser):
    """argparse's parser whose bad argument is one line, as :func:`run_main` reports a user error:
    ``PROG: error: MESSAGE (PROG --help: the options)`` and status 2, without the usage block that
    argparse prints above it."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {' '.join(message.split())} ({self.prog} --help: the options)\n")


def run_main(main: Callable[[list[str] | None], object], argv: list[str] | None = None,
             prog: str | None = None) -> None:
    """Call ``main(argv)``; on a user error print ``PROG: error: MESSAGE`` (one line) to stderr and
    exit with status 2; on Ctrl-C print ``PROG: interrupted`` and exit with status 130 (the
    shell's for SIGINT), without a traceback. ``prog`` defaults to the script's file name.

    Use as ``if __name__ == "__main__": run_main(main)``; tests call ``main`` directly.
    """
    prog = prog or Path(sys.argv[0]).name
    try:
        main(argv)
    except USER_ERRORS as exc:
        _release_frames(exc)
        print(f"{prog}: error: {error_text(exc)}", file=sys.stderr)
        raise SystemExit(2) from None
    except KeyboardInterrupt as exc:
        _release_frames(exc)
        print(f"\n{prog}: interrupted", file=sys.stderr)
        raise SystemExit(130) from None


def _release_frames(exc: BaseException | None) -> None:
    """Drop the frames the tracebacks of ``exc`` and the exceptions it arose from hold, and what they
    held: a progress bar iterated in a list comprehension lives in one and closes, drawing itself once
    more, as it goes. Dropped before the error line is printed, it is drawn above the line, not below
    it as if the run went on."""
    while exc is not None:  # Python keeps the chain free of cycles
        exc.__traceback__ = None
        exc = exc.__context__


class _ConsoleHandler(logging.StreamHandler):
    """Writes each record through ``tqdm.write``: a progress bar on the console is cleared and
    redrawn below the line instead of the line being appended to the bar. (tqdm's own
    ``logging_redirect_tqdm`` does this for the handlers present when its ``with`` block starts;
    an entry point's handler is made by ``logging.basicConfig`` and lasts the whole process.)"""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            tqdm.write(self.format(record), file=self.stream)
        except RecursionError:
            raise
        except Exception:
            self.handleError(record)


def console_logging(fmt: str = "%(asctime)s %(name)s: %(message)s") -> None:
    """INFO and above on stderr, one line per record, clear of any tqdm progress bar; for entry
    points, after argument parsing (``logging.basicConfig``: the first configuration stands)."""
    logging.basicConfig(level=logging.INFO, format=fmt, datefmt="%H:%M:%S", handlers=[_ConsoleHandler(sys.stderr)])
