"""The history's database: its schema (SQLAlchemy Core), the migrations that build and upgrade it,
and the writes and queries of ``hil history`` and the reports.

Tables (every name starts ``hil_``, so the store can share a team's database):

* ``hil_runs``: one row per run; ``uuid`` is the natural key (a run recorded twice, an import of a
  report already recorded, is one row), ``id`` the short number people say ("run 212"). ``complete``
  is set last, in the transaction that writes the whole record: a run killed while it wrote leaves
  nothing, and a row without ``complete`` is never read as a run;
* ``hil_run_duts``: each controller of a run: spec, identity read from it, build, profile;
* ``hil_requirements``: each requirement's verdict;
* ``hil_measurements``: each budget measured: measured, limit, margin, unit, verdict, test, and the
  figure's interval where the report gives one;
* ``hil_replays``: the replay files of failing examples (path, hash, content);
* ``hil_schema``: the migrations applied (version, description, when).

Migrations are a short list of Python steps (``MIGRATIONS``), not alembic: the store must build and
upgrade itself on first use, at a station with no migration scripts folder or ini file to ship, in
one transaction that also holds the lock against a second process doing the same; the schema has
six tables, and each step is a few ``CREATE``/``ALTER`` statements both SQLite and PostgreSQL read.
A store newer than this package is refused in one line; an older one is upgraded.
"""

from __future__ import annotations

import datetime
from dataclasses import dataclass

import sqlalchemy as sa
from sqlalchemy.exc import IntegrityError, SQLAlchemyError

from .location import scrub, shown
from .record import RunRecord, iso

#: the schema this package reads and writes
SCHEMA_VERSION = 2
#: PostgreSQL: the advisory lock a migration holds (two stations opening a new database at once)
_MIGRATION_LOCK = 0x4849_4C48  # "HILH"
#: how long a write waits for a lock another writer holds before it gives up (one warning line)
LOCK_WAIT_S = 10.0


class HistoryError(ValueError):
    """The store cannot be used: one line that names it (its password hidden) and says why."""


def _define(metadata: sa.MetaData, version: int) -> dict[str, sa.Table]:
    """The tables as migration ``version`` leaves them (1: the first schema; 2: + intervals, replay content)."""
    runs = sa.Table(
        "hil_runs", metadata,
        sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
        sa.Column("uuid", sa.String(36), nullable=False, unique=True),
        sa.Column("complete", sa.Boolean, nullable=False, default=False),
        sa.Column("kind", sa.String(16), nullable=False),
        sa.Column("started", sa.DateTime, index=True),
        sa.Column("finished", sa.DateTime),
        sa.Column("verdict", sa.String(16), index=True),
        sa.Column("report_complete", sa.Boolean),
        sa.Column("exit_status", sa.Integer),
        sa.Column("seed", sa.BigInteger),
        sa.Column("hypothesis_seed", sa.String(64)),
        sa.Column("framework_version", sa.String(64)),
        sa.Column("framework_commit", sa.String(64)),
        sa.Column("station", sa.String(128), index=True),
        sa.Column("host", sa.String(128)),
        sa.Column("command", sa.Text),
        sa.Column("dut_specs", sa.Text),
        sa.Column("plant", sa.Text),
        sa.Column("plant_sha256", sa.String(64)),
        sa.Column("budgets", sa.Text),
        sa.Column("budgets_sha256", sa.String(64)),
        sa.Column("report_path", sa.Text),
        sa.Column("seeded_defect", sa.String(128)),
        sa.Column("session", sa.JSON),
        sa.Column("verdict_reasons", sa.JSON),
        sa.Column("counts", sa.JSON),
    )
    duts = sa.Table(
        "hil_run_duts", metadata,
        sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
        sa.Column("run_id", sa.Integer, sa.ForeignKey("hil_runs.id", ondelete="CASCADE"), nullable=False, index=True),
        sa.Column("dut", sa.String(128), nullable=False),
        sa.Column("spec", sa.Text),
        sa.Column("vendor", sa.String(64)),
        sa.Column("product", sa.String(64)),
        sa.Column("revision", sa.String(64)),
        sa.Column("serial", sa.String(128)),
        sa.Column("firmware", sa.String(256), index=True),
        sa.Column("firmware_sha256", sa.String(64), index=True),
        sa.Column("profile", sa.Text),
        sa.Column("profile_sha256", sa.String(64)),
        sa.Column("identity_key", sa.String(256), nullable=False, index=True),
        sa.Column("build", sa.String(256)),
        sa.Column("identity", sa.JSON),
    )
    reqs = sa.Table(
        "hil_requirements", metadata,
        sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
        sa.Column("run_id", sa.Integer, sa.ForeignKey("hil_runs.id", ondelete="CASCADE"), nullable=False, index=True),
        sa.Column("requirement", sa.String(64), nullable=False),
        sa.Column("verdict", sa.String(16), nullable=False),
    )
    meas = sa.Table(
        "hil_measurements", metadata,
        sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
        sa.Column("run_id", sa.Integer, sa.ForeignKey("hil_runs.id", ondelete="CASCADE"), nullable=False, index=True),
        sa.Column("requirement", sa.String(64)),
        sa.Column("budget", sa.String(128), nullable=False),
        sa.Column("test", sa.Text),
        sa.Column("dut", sa.String(128)),
        sa.Column("identity_key", sa.String(256)),
        sa.Column("measured", sa.Float),
        sa.Column("limit_value", sa.Float),
        sa.Column("margin", sa.Float),
        sa.Column("unit", sa.String(32)),
        sa.Column("verdict", sa.String(16)),
        sa.Column("limit_kind", sa.String(8)),
        sa.Index("ix_hil_measurements_identity_budget", "identity_key", "budget"),
    )
    replays = sa.Table(
        "hil_replays", metadata,
        sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
        sa.Column("run_id", sa.Integer, sa.ForeignKey("hil_runs.id", ondelete="CASCADE"), nullable=False, index=True),
        sa.Column("test", sa.Text),
        sa.Column("path", sa.Text),
        sa.Column("sha256", sa.String(64)),
    )
    schema = sa.Table(
        "hil_schema", metadata,
        sa.Column("version", sa.Integer, primary_key=True, autoincrement=False),
        sa.Column("description", sa.Text, nullable=False),
        sa.Column("applied", sa.DateTime, nullable=False),
    )
    if version >= 2:
        meas.append_column(sa.Column("interval_low", sa.Float))
        meas.append_column(sa.Column("interval_high", sa.Float))
        replays.append_column(sa.Column("content", sa.Text))
    return {"runs": runs, "duts": duts, "requirements": reqs, "measurements": meas, "replays": replays,
            "schema": schema}


#: the tables as this package reads and writes them (the last migration's)
METADATA = sa.MetaData()
T = _define(METADATA, SCHEMA_VERSION)


def _migrate_1(conn) -> None:
    _define(sa.MetaData(), 1)["runs"].metadata.create_all(conn)


def _migrate_2(conn) -> None:
    for table, column, kind in (("hil_measurements", "interval_low", "FLOAT"),
                                ("hil_measurements", "interval_high", "FLOAT"),
                                ("hil_replays", "content", "TEXT")):
        conn.execute(sa.text(f"ALTER TABLE {table} ADD COLUMN {column} {kind}"))


#: (version, what it does, the step): applied in order, each once, in the transaction that records it
MIGRATIONS = (
    (1, "runs, controllers, requirement verdicts, measurements, replays", _migrate_1),
    (2, "a measurement's interval (the figure's run-to-run spread), a replay file's content", _migrate_2),
)


def _engine(url: str) -> sa.Engine:
    """An engine that waits ``LOCK_WAIT_S`` for a lock and gives up on an unreachable server in a few seconds."""
    u = sa.engine.make_url(url)
    if u.get_backend_name() == "sqlite":
        if u.database and u.database != ":memory:":
            from pathlib import Path

            Path(u.database).parent.mkdir(parents=True, exist_ok=True)
        engine = sa.create_engine(u, connect_args={"timeout": LOCK_WAIT_S})

        @sa.event.listens_for(engine, "connect")
        def _connect(dbapi_conn, _record):
            dbapi_conn.isolation_level = None  # transactions begun below, not by the driver (pysqlite)
            dbapi_conn.execute("PRAGMA foreign_keys = ON")

        @sa.event.listens_for(engine, "begin")
        def _begin(conn):
            # a writer takes the write lock at its start: two writers queue on the busy timeout
            # instead of one failing at once on a lock upgrade
            conn.exec_driver_sql("BEGIN IMMEDIATE" if conn.info.get("write") else "BEGIN")

        return engine
    if u.get_backend_name() == "postgresql":
        return sa.create_engine(u, pool_pre_ping=True, connect_args={
            "connect_timeout": 5, "options": f"-c lock_timeout={int(LOCK_WAIT_S * 1000)}"})
    return sa.create_engine(u)


@dataclass
class Store:
    """An open history store (``Store.open(url)``)."""

    url: str
    engine: sa.Engine

    @classmethod
    def open(cls, url: str, *, migrate: bool = True) -> Store:
        """The store at ``url``, built or upgraded to ``SCHEMA_VERSION`` (``migrate``); a newer
        schema, a file that is no database, a server that cannot be reached: ``HistoryError``."""
        try:
            engine = _engine(url)
        except Exception as exc:  # a URL SQLAlchemy cannot read, a driver not installed
            raise HistoryError(f"{shown(url)}: {_line(exc)}") from None
        store = cls(url, engine)
        try:
            version = store.version()
            if version > SCHEMA_VERSION:
                raise HistoryError(
                    f"{shown(url)}: schema version {version} is newer than this bldc-hil reads ({SCHEMA_VERSION}): "
                    "upgrade bldc-hil, or point --history elsewhere")
            if version < SCHEMA_VERSION and migrate:
                store._upgrade()
        except HistoryError:
            engine.dispose()
            raise
        except SQLAlchemyError as exc:
            engine.dispose()
            raise HistoryError(f"{shown(url)}: {_line(exc)}") from None
        return store

    @property
    def shown(self) -> str:
        return shown(self.url)

    def close(self) -> None:
        self.engine.dispose()

    def _write(self):
        """A connection whose transaction takes the write lock at once (SQLite: BEGIN IMMEDIATE)."""
        conn = self.engine.connect()
        conn.info["write"] = True
        return conn

    def version(self) -> int:
        with self.engine.connect() as conn:
            if not sa.inspect(conn).has_table("hil_schema"):
                return 0
            return int(conn.execute(sa.select(sa.func.max(T["schema"].c.version))).scalar() or 0)

    def _upgrade(self) -> None:
        with self._write() as conn, conn.begin():
            if conn.dialect.name == "postgresql":
                conn.execute(sa.select(sa.func.pg_advisory_xact_lock(_MIGRATION_LOCK)))
            have = 0
            if sa.inspect(conn).has_table("hil_schema"):  # read again under the lock: another may have migrated
                have = int(conn.execute(sa.select(sa.func.max(T["schema"].c.version))).scalar() or 0)
            if have > SCHEMA_VERSION:
                raise HistoryError(f"{self.shown}: schema version {have} is newer than this bldc-hil reads "
                                   f"({SCHEMA_VERSION}): upgrade bldc-hil, or point --history elsewhere")
            for version, description, step in MIGRATIONS:
                if version > have:
                    step(conn)
                    conn.execute(T["schema"].insert().values(
                        version=version, description=description, applied=_now()))

    # ------------------------------------------------------------------------------ writing
    def write(self, record: RunRecord) -> tuple[int, bool]:
        """Record a run in one transaction, ``complete`` set last: (its id, False when that UUID
        was recorded already, then nothing is written twice)."""
        with self._write() as conn, conn.begin():
            found = conn.execute(sa.select(T["runs"].c.id, T["runs"].c.complete)
                                 .where(T["runs"].c.uuid == record.uuid)).first()
            if found is not None and found.complete:
                return int(found.id), False
            row = {k: getattr(record, k) for k in (
                "kind", "started", "finished", "verdict", "report_complete", "exit_status", "seed", "hypothesis_seed",
                "framework_version", "framework_commit", "station", "host", "command", "dut_specs", "plant",
                "plant_sha256", "budgets", "budgets_sha256", "report_path", "seeded_defect", "session",
                "verdict_reasons", "counts")}
            row["complete"] = False
            if found is None:
                try:
                    with conn.begin_nested():
                        inserted = conn.execute(T["runs"].insert().values(uuid=record.uuid, **row))
                        run_id = inserted.inserted_primary_key[0]
                except IntegrityError:  # the same UUID written by another process this instant
                    found = conn.execute(sa.select(T["runs"].c.id).where(T["runs"].c.uuid == record.uuid)).first()
                    return int(found.id), False
            else:  # a row begun and never completed (a killed writer of an older version): written afresh
                run_id = found.id
                for name in ("duts", "requirements", "measurements", "replays"):
                    conn.execute(T[name].delete().where(T[name].c.run_id == run_id))
                conn.execute(T["runs"].update().where(T["runs"].c.id == run_id).values(**row))
            rows = {
                "duts": [{**{k: v for k, v in d.__dict__.items()}, "run_id": run_id} for d in record.duts],
                "requirements": [{**r, "run_id": run_id} for r in record.requirements],
                "measurements": [{**m, "run_id": run_id} for m in record.measurements],
                "replays": [{**r, "run_id": run_id} for r in record.replays],
            }
            for name, values in rows.items():
                if values:
                    conn.execute(T[name].insert(), values)
            conn.execute(T["runs"].update().where(T["runs"].c.id == run_id).values(complete=True))
            return int(run_id), True

    # ------------------------------------------------------------------------------ reading
    def runs(self, *, dut: str | None = None, firmware: str | None = None, station: str | None = None,
             verdict: str | None = None, kind: str | None = None, since: datetime.datetime | None = None,
             until: datetime.datetime | None = None, limit: int | None = 50) -> list[dict]:
        """The complete runs matching every filter given, newest first: ``dut`` matches a controller's
        identity (vendor, product, serial), its serial, spec or id; ``firmware`` its firmware text,
        build or content hash (a prefix)."""
        r, d = T["runs"], T["duts"]
        q = sa.select(r).where(r.c.complete.is_(True))
        if dut:
            like = f"%{dut}%"
            q = q.where(r.c.id.in_(sa.select(d.c.run_id).where(sa.or_(
                d.c.identity_key.like(like), d.c.serial == dut, d.c.dut == dut, d.c.spec.like(like)))))
        if firmware:
            q = q.where(r.c.id.in_(sa.select(d.c.run_id).where(sa.or_(
                d.c.firmware.like(f"%{firmware}%"), d.c.build.like(f"%{firmware}%"),
                d.c.firmware_sha256.like(f"{firmware}%")))))
        if station:
            q = q.where(r.c.station == station)
        if verdict:
            q = q.where(sa.func.upper(r.c.verdict) == verdict.upper())
        if kind:
            q = q.where(r.c.kind == kind)
        if since:
            q = q.where(r.c.started >= since)
        if until:
            q = q.where(r.c.started < until)
        q = q.order_by(r.c.started.desc(), r.c.id.desc())
        if limit:
            q = q.limit(limit)
        with self.engine.connect() as conn:
            runs = [dict(row._mapping) for row in conn.execute(q)]
            ids = [x["id"] for x in runs]
            duts: dict[int, list] = {}
            if ids:
                for row in conn.execute(sa.select(d).where(d.c.run_id.in_(ids)).order_by(d.c.id)):
                    duts.setdefault(row.run_id, []).append(dict(row._mapping))
        for x in runs:
            x["duts"] = duts.get(x["id"], [])
        return runs

    def find(self, ref: str) -> dict:
        """A complete run by its number, its UUID or a UUID prefix (8 characters at least)."""
        r = T["runs"]
        ref = str(ref).strip()
        with self.engine.connect() as conn:
            if ref.isdigit():
                q = sa.select(r.c.id).where(r.c.id == int(ref))
            elif len(ref) >= 8:
                q = sa.select(r.c.id).where(r.c.uuid.like(f"{ref}%"))
            else:
                raise HistoryError(f"{ref!r}: give a run's number or its UUID (8 characters at least)")
            ids = [row.id for row in conn.execute(q.where(r.c.complete.is_(True)).limit(2))]
        if not ids:
            raise HistoryError(f"no run {ref} in {self.shown}")
        if len(ids) > 1:
            raise HistoryError(f"{ref!r} names more than one run in {self.shown}: give more of the UUID")
        return self.run(ids[0])

    def run(self, run_id: int) -> dict:
        """Everything recorded of run ``run_id``."""
        with self.engine.connect() as conn:
            row = conn.execute(sa.select(T["runs"]).where(T["runs"].c.id == run_id)).first()
            if row is None:
                raise HistoryError(f"no run {run_id} in {self.shown}")
            out = dict(row._mapping)
            for name in ("duts", "requirements", "measurements", "replays"):
                t = T[name]
                out[name] = [dict(x._mapping) for x in conn.execute(sa.select(t).where(t.c.run_id == run_id)
                                                                     .order_by(t.c.id))]
        return out

    def series(self, identity: str, budget: str, *, before: datetime.datetime | None = None,
               test: str | None = None, last: int | None = None) -> list[dict]:
        """Budget ``budget``'s figures over the complete runs of the device ``identity`` (oldest
        first; ``before`` a time, ``last`` runs at most): run, started, build, verdicts, measured,
        limit, margin, interval, test."""
        r, m, d = T["runs"], T["measurements"], T["duts"]
        q = (sa.select(r.c.id.label("run"), r.c.uuid, r.c.started, r.c.verdict.label("run_verdict"), r.c.station,
                       m.c.test, m.c.requirement, m.c.budget, m.c.measured, m.c.limit_value, m.c.margin, m.c.unit,
                       m.c.verdict, m.c.limit_kind, m.c.interval_low, m.c.interval_high, d.c.build)
             .select_from(m.join(r, r.c.id == m.c.run_id)
                          .outerjoin(d, sa.and_(d.c.run_id == m.c.run_id, d.c.dut == m.c.dut)))
             .where(m.c.identity_key == identity, m.c.budget == budget, r.c.complete.is_(True)))
        if before is not None:
            q = q.where(r.c.started < before)
        if test is not None:
            q = q.where(m.c.test == test)
        q = q.order_by(r.c.started.desc(), r.c.id.desc())
        if last:
            q = q.limit(last)
        with self.engine.connect() as conn:
            rows = [dict(x._mapping) for x in conn.execute(q)]
        return rows[::-1]

    def history_of(self, identities: list[str], budgets: list[str], *, before: datetime.datetime | None,
                   exclude: str | None = None, last: int = 50) -> list[dict]:
        """The figures of ``budgets`` over the last ``last`` complete runs of each device of
        ``identities`` (oldest first), the run ``exclude`` (a UUID) left out: what a report compares
        its own figures with."""
        r, m, d = T["runs"], T["measurements"], T["duts"]
        out: list[dict] = []
        with self.engine.connect() as conn:
            for identity in identities:
                measured = sa.select(m.c.id).where(m.c.run_id == r.c.id, m.c.identity_key == identity)
                runs = sa.select(r.c.id).where(measured.exists(), r.c.complete.is_(True))
                if before is not None:
                    runs = runs.where(r.c.started < before)
                if exclude:
                    runs = runs.where(r.c.uuid != exclude)
                ids = [x.id for x in conn.execute(runs.order_by(r.c.started.desc(), r.c.id.desc()).limit(last))]
                if not ids:
                    continue
                q = (sa.select(r.c.id.label("run"), r.c.uuid, r.c.started, r.c.verdict.label("run_verdict"),
                               m.c.identity_key, m.c.test, m.c.dut, m.c.requirement, m.c.budget, m.c.measured,
                               m.c.limit_value,
                               m.c.margin, m.c.unit, m.c.verdict, m.c.limit_kind, m.c.interval_low,
                               m.c.interval_high, d.c.build)
                     .select_from(m.join(r, r.c.id == m.c.run_id)
                                  .outerjoin(d, sa.and_(d.c.run_id == m.c.run_id, d.c.dut == m.c.dut)))
                     .where(m.c.run_id.in_(ids), m.c.identity_key == identity, m.c.budget.in_(budgets))
                     .order_by(r.c.started, r.c.id))
                out += [dict(x._mapping) for x in conn.execute(q)]
        return out

    def identities(self, budget: str) -> list[str]:
        """The devices that measured ``budget``."""
        m = T["measurements"]
        q = sa.select(m.c.identity_key).where(m.c.budget == budget).distinct().order_by(m.c.identity_key)
        with self.engine.connect() as conn:
            return [x.identity_key for x in conn.execute(q)]

    def counts(self) -> dict:
        with self.engine.connect() as conn:
            return {name: int(conn.execute(sa.select(sa.func.count()).select_from(T[name])).scalar() or 0)
                    for name in ("runs", "measurements")}


def _now() -> datetime.datetime:
    return datetime.datetime.now(datetime.timezone.utc).replace(tzinfo=None)


def _line(exc: BaseException) -> str:
    """An exception as one line: the driver's first line, any password scrubbed."""
    orig = getattr(exc, "orig", None) or exc
    text = str(orig).strip().splitlines()
    return scrub(f"{type(orig).__name__}: {text[0] if text else ''}")


def plain(row: dict) -> dict:
    """A row as JSON data (times in ISO 8601 UTC)."""
    return {k: (iso(v) if isinstance(v, datetime.datetime) else
                [plain(x) for x in v] if isinstance(v, list) and v and isinstance(v[0], dict) else v)
            for k, v in row.items()}
