"""Where the history lives: ``--history URL`` over ``HIL_HISTORY`` over the default file, and how a
URL is shown (never with its password).

URL forms (docs/history.md):

* ``off`` (also ``none``, ``no``, ``false``, ``0``): nothing is recorded or read;
* a path (``history.sqlite``, ``/srv/hil/history.sqlite``) or ``sqlite:///PATH``: an SQLite file;
* ``postgresql+psycopg://USER[:PASSWORD]@HOST[:PORT]/DB`` (``postgresql://`` means the same: psycopg 3
  is the driver this package installs): a PostgreSQL database a team shares.

Standard library only: the plugin resolves the location of every run without loading SQLAlchemy.
"""

from __future__ import annotations

import os
import re
import sys
from pathlib import Path

#: the environment variables: the store's URL, the station's name, the kind of run (set by ``hil qualify``)
HISTORY_ENV = "HIL_HISTORY"
STATION_ENV = "HIL_STATION"
KIND_ENV = "HIL_RUN_KIND"
#: settings that turn the history off
OFF = ("off", "none", "no", "false", "0")
#: a URL's password, for text that never went through SQLAlchemy's URL (an error message)
_PASSWORD = re.compile(r"(://[^:/@\s]+:)([^@\s]+)(@)")


def default_location() -> Path:
    """The default SQLite file: ``$XDG_DATA_HOME/bldc-hil/history.sqlite`` (``~/.local/share`` when
    XDG_DATA_HOME is unset; ``%LOCALAPPDATA%`` on Windows). One file per user, whatever the report
    directory: a year of runs of every project and station of that user in one place."""
    if sys.platform == "win32" and os.environ.get("LOCALAPPDATA"):
        base = Path(os.environ["LOCALAPPDATA"])
    else:
        base = Path(os.environ.get("XDG_DATA_HOME") or Path.home() / ".local" / "share")
    return base / "bldc-hil" / "history.sqlite"


def resolve(setting: str | None = None) -> str | None:
    """The store's URL from ``setting`` (``--history``), else ``HIL_HISTORY``, else the default
    file; None when the history is off."""
    text = setting if setting not in (None, "") else os.environ.get(HISTORY_ENV, "")
    text = text.strip()
    if not text:
        return f"sqlite:///{default_location()}"
    if text.lower() in OFF:
        return None
    if text.startswith("postgresql://") or text.startswith("postgres://"):
        return "postgresql+psycopg://" + text.split("://", 1)[1]
    if "://" not in text:  # a path
        return f"sqlite:///{Path(text).expanduser().resolve()}"
    return text


def shown(url: str | None) -> str:
    """``url`` as it may be printed or written: the password replaced by ``***``."""
    if url is None:
        return "off"
    try:
        from sqlalchemy.engine import make_url

        return make_url(url).render_as_string(hide_password=True)
    except Exception:  # not a URL SQLAlchemy reads: hide what looks like a password all the same
        return scrub(url)


def scrub(text: str) -> str:
    """Any ``scheme://user:password@`` in ``text`` with the password replaced (error messages)."""
    return _PASSWORD.sub(r"\1***\3", str(text))


def station(configured: str | None = None) -> str:
    """The station's name: configured (``--station``, ``hil_station``), else ``HIL_STATION``, else
    the host name."""
    import platform

    return (configured or os.environ.get(STATION_ENV) or platform.node() or "unknown").strip()
