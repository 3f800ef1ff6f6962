"""What a run calls to be remembered: ``RunHistory`` looks back before the run's report is written
for the last time (trends, regressions) and records the run after. It never costs a run its report:
a store that is locked, corrupt, newer than this package or unreachable is one warning line, and
the report and the exit status are what they would have been without it.
"""

from __future__ import annotations

import os
import time
import uuid as uuidlib
from pathlib import Path

from . import location
from .location import KIND_ENV, resolve


class RunHistory:
    """The history of one run: ``setting`` is ``--history`` (None: ``HIL_HISTORY``, else the default
    file), ``station`` the configured station name (None: ``HIL_STATION``, else the host)."""

    def __init__(self, setting: str | None = None, station: str | None = None, kind: str | None = None):
        self.url = resolve(setting)
        self.station = location.station(station)
        self.kind = kind or os.environ.get(KIND_ENV) or None
        self.uuid = str(uuidlib.uuid4())
        self.warning: str | None = None  #: the one warning line, once something failed
        self.recorded: dict | None = None  #: run id, whether new, the store shown, seconds it took
        self.looked_back: dict | None = None
        self._store = None

    @property
    def enabled(self) -> bool:
        return self.url is not None and self.warning is None

    def session_info(self) -> dict:
        """What the report's session names of the run (no store URL: it may hold a password)."""
        from .record import framework_commit

        return {"run_uuid": self.uuid, "station": self.station, "framework_commit": framework_commit(),
                **({"run_kind": self.kind} if self.kind else {})}

    def _fail(self, exc: BaseException) -> None:
        from .location import scrub

        text = str(exc).strip().splitlines()
        line = scrub(text[0] if text else type(exc).__name__)
        if not any(s in line for s in ("sqlite", "postgresql", "://")):
            line = f"{location.shown(self.url)}: {line}"
        self.warning = (f"hil history: warning: not recorded: {line} (the reports are written, the exit status "
                        "unchanged)")
        self.close()

    def _open(self):
        if self._store is None:
            from .store import Store

            self._store = Store.open(self.url)
        return self._store

    def look_back(self, content: dict) -> dict | None:
        """The trends and regressions of this run's figures against the device's earlier runs (the
        ``history`` of the report's content), or None (history off, or failing: one warning)."""
        if not self.enabled:
            return None
        try:
            from .compare import look_back
            from .record import from_report, utc

            record = from_report(content)
            identities = {m["dut"]: m["identity_key"] for m in record.measurements}
            budgets = sorted({m["budget"] for m in record.measurements})
            rows = self._open().history_of(sorted(set(identities.values())), budgets, before=None, exclude=self.uuid) \
                if identities and budgets else []
            now = utc(content.get("session", {}).get("started"))
            rows = [r for r in rows if now is None or r["started"] is None or r["started"] <= now]
            self.looked_back = {"store": location.shown(self.url), **look_back(content, rows, identities)}
            return self.looked_back
        except Exception as exc:  # never the run's report: one line
            self._fail(exc)
            return None

    def record(self, content: dict, report_dir: Path | None) -> dict | None:
        """Record the run (one transaction); None when the history is off or failed (one warning)."""
        if not self.enabled:
            return None
        t0 = time.perf_counter()
        try:
            from .record import from_report

            rec = from_report(content, report_dir=report_dir, station=self.station, kind=self.kind)
            run_id, new = self._open().write(rec)
            self.recorded = {"run": run_id, "uuid": rec.uuid, "new": new, "store": location.shown(self.url),
                             "seconds": time.perf_counter() - t0}
            return self.recorded
        except Exception as exc:
            self._fail(exc)
            return None
        finally:
            self.close()

    def close(self) -> None:
        if self._store is not None:
            try:
                self._store.close()
            except Exception:
                pass
            self._store = None

    def summary_lines(self) -> list[str]:
        """What the terminal says of the history at the end of the run."""
        if self.warning:
            return [self.warning]
        lines = []
        if self.recorded:
            r = self.recorded
            lines.append(f"hil history: run {r['run']} recorded in {r['store']}" if r["new"]
                         else f"hil history: run {r['run']} was recorded already in {r['store']}")
        for reg in (self.looked_back or {}).get("regressions", []):
            lines.append(f"  REGRESSION {reg['line']}")
        return lines


def record_campaign(result, history: str | None = None, station: str | None = None) -> list[str]:
    """Record a finished ``hil campaign`` (``hil.campaign.runner.CampaignResult``); the lines to print
    (one warning line when the store fails, nothing when the history is off)."""
    import datetime
    import sys

    h = RunHistory(history, station, kind="campaign")
    if not h.enabled:
        return []
    try:
        from .record import from_campaign

        spec = result.spec
        budgets = {b: {"requirement": spec.budgets[b].requirement, "unit": spec.budgets[b].unit,
                       "limit": spec.budgets[b].limit, "kind": spec.budgets[b].kind} for b in spec.checked}
        rec = from_campaign(result.summary(), result.rows, budgets, out_dir=result.out_dir,
                            plant_sha256=spec.plant.config_hash(), station=h.station, run_uuid=h.uuid,
                            finished=datetime.datetime.now(datetime.timezone.utc).replace(tzinfo=None),
                            command=" ".join(["hil", *sys.argv[1:]]))
        run_id, new = h._open().write(rec)
        h.recorded = {"run": run_id, "uuid": rec.uuid, "new": new, "store": location.shown(h.url), "seconds": 0.0}
    except Exception as exc:
        h._fail(exc)
    finally:
        h.close()
    return h.summary_lines()
