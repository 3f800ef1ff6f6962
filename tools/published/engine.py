"""Every figure published in README.md and docs/, computed from the code at HEAD.

    python tools/figures.py                 # compute every group, write docs/figures.json, render the docs
    python tools/figures.py --only demo ... # compute these groups only (the others keep their values)
    python tools/figures.py --quick         # recompute the quick subset; exit 1 on drift beyond tolerance
    python tools/figures.py --render        # rewrite the docs from docs/figures.json (no computing)
    python tools/figures.py --check         # exit 1 where a doc disagrees with docs/figures.json, a group's
                                            # content is not what the tool wrote, its commit is not HEAD's
                                            # ancestor, or a group recomputed differs: every group whose
                                            # declared inputs changed since its commit is recomputed
    python tools/figures.py --stale         # the groups --check would recompute, and why
    python tools/figures.py --check --all   # the release check: recompute EVERY group and compare figures and
                                            # table cells with the file (slow: the whole test suite is one group);
                                            # its record is kept in the file and shown in README.md
    python tools/figures.py --check --only G ...  # the same for some groups

A figure lives in ``docs/figures.json`` with its value, unit, tolerance and the provenance of its group
(commit, command, seeds, duration, machine). A document shows it between markers, which ``--render``
fills in and ``--check`` (and ``tests/test_figures.py``) holds to the file:

    <!-- fig:demo.rms_deg_e -->3.986<!-- /fig -->
    <!-- figtable:pump_predictors -->
    | ... rendered table ... |
    <!-- /figtable -->

So no published number is typed by hand: a doc that says something else fails the test, and a code
change that moves a quick figure beyond its tolerance fails ``--quick`` in CI.

What ``--check`` holds:

- every marked figure and table of the docs is the file's;
- every group's content (figures, tables, blocks, provenance) hashes to the digest the tool wrote
  with it: a number, a table cell or a provenance commit edited by hand in the file fails. The digest
  has no key, and a key would not help: in an open repository anyone can read it, and a forger runs
  the tool's own ``digest()``. It catches an edit by hand, never a forgery;
- every group's provenance commit is a commit of this repository and an ancestor of HEAD
  (``git merge-base --is-ancestor``); in a clone without history (``git clone --depth 1``, an
  archive) the check says that it could not check, and does not pass it silently;
- every group whose declared inputs (``Group.inputs``: the code it runs and the data it reads)
  changed between its provenance commit and the working tree, or whose commit is not an ancestor, is
  recomputed and compared figure by figure and cell by cell: such a group cannot pass on its file
  entry. A forged cell whose group names an old commit (the root commit, say) is recomputed and fails.

What only a recompute catches: a figure rewritten with a provenance commit newer than its group's
last input change (the forger names HEAD). ``tests/test_figures.py`` recomputes the quick groups on
every CI run, ``tests/test_figures_rotation.py`` one of the rotating groups in turn
(:func:`rotation_group`); ``--check --all`` (before each release) recomputes every group.

Where things are. This module is the engine: the figures file, digests and provenance, the checks,
the rendering, the ledger of unmarked numbers, the inputs' globs, the rotation and the command line
(``tools/figures.py`` runs :func:`main`). ``model.py`` declares what a group is (:class:`Group`) and
what its producer returns (:class:`Run` of :class:`Figure`). ``producers/`` holds one module per
producer, each declaring its groups (``GROUPS``) with their inputs beside its code;
``producers/__init__.py`` lists them in the order the checks name them and the rotation takes its
turns. A new group is that module and its line in the list.

What a group's inputs name. Before the split every producer was code of one file, and that file was
among every group's inputs. The rule is the same, now at the scale of a file: a group's inputs name
the code that produces its figures, its producer's own module and ``producers/common.py`` (how a
command is run and its output read, shared by every producer), added by
``producers.common.inputs``; a change to a producer makes its own groups stale, not the others. The
engine and ``model.py`` are in no group's inputs: they compute no figure. What they do to the
figures (store them, hash them, render them, compare them) is held on every ``--check`` without a
recompute (the digest, the pages against the file) and by ``tests/test_figures.py``, so an edit of
the engine does not make every group stale. ``tests/test_figures.py`` holds every group to its
producer's module.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import hashlib
import json
import multiprocessing
import os
import platform
import re
import subprocess
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

from .model import ROOT, Figure, Group, Run
from .producers import GROUPS

FIGURES_FILE = ROOT / "docs" / "figures.json"
PUBLISHED = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

FIG_MARK = re.compile(r"<!-- fig:(?P<key>[\w.\-]+) -->(?P<text>.*?)<!-- /fig -->", re.S)
#: where the docs say when every group was last recomputed and compared (``--check --all``)
CHECK_MARK = re.compile(r"<!-- figcheck -->(?P<text>.*?)<!-- /figcheck -->", re.S)
TABLE_MARK = re.compile(
    r"(?P<open><!-- figtable:(?P<name>[\w\-]+) -->\n)(?P<body>.*?)(?P<close><!-- /figtable -->)", re.S
)


# ---------------------------------------------------------------- the file and the docs


def _commit() -> str:
    """HEAD, marked when tracked files differ from it."""
    commit = _git("rev-parse", "HEAD").stdout.strip()
    dirty = bool(_git("status", "--porcelain", "--untracked-files=no").stdout.strip())
    return commit + ("+uncommitted" if dirty else "")


def _provenance(group: Group, run: Run, duration_s: float, commit: str) -> dict:
    return {
        "what": group.what,
        "commit": commit,
        "commands": run.commands,
        "seeds": run.seeds,
        "duration_s": round(duration_s, 1),
        "date": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
                   f"load average {os.getloadavg()[0]:.1f} at the end",
        "quick": group.quick,
    }


def compute(groups: list[Group]) -> dict[str, dict]:
    out = {}
    with tempfile.TemporaryDirectory(prefix="hil-figures-") as tmp:
        work = Path(tmp)
        for g in groups:
            print(f"figures: {g.name}: {g.what} ...", flush=True)
            t0 = time.perf_counter()
            commit = _commit()  # before the run: a run may write files of its own (the suite's screenshots)
            run = g.produce(work)
            dt = time.perf_counter() - t0
            out[g.name] = {
                "provenance": _provenance(g, run, dt, commit),
                "figures": {k: f.to_json() for k, f in run.figures.items()},
                "tables": run.tables,
                "blocks": run.blocks,
            }
            out[g.name]["digest"] = digest(json.loads(json.dumps(out[g.name])))
            print(f"figures: {g.name}: {len(run.figures)} figures in {dt:.0f} s", flush=True)
    return out


def _compute_one(name: str) -> dict[str, dict]:
    """:func:`compute` of the group ``name`` (in a worker process of :func:`compute_each`)."""
    return compute([g for g in GROUPS if g.name == name])


def compute_each(groups: list[Group], jobs: int, last_s: dict[str, float]) -> dict[str, dict | str]:
    """Each group computed on its own: its entry, or why its producer failed (the others still run).
    ``jobs`` > 1: that many groups at once, each in a fresh process, the longest first (by ``last_s``,
    their durations when last computed) so the last to finish is a short one; a group's figures do
    not depend on what runs beside it, its wall time does (its provenance keeps the load)."""
    failures = (RuntimeError, OSError, subprocess.SubprocessError, ValueError, KeyError)
    out: dict[str, dict | str] = {}
    if jobs <= 1:
        for g in groups:
            try:
                out.update(compute([g]))
            except failures as exc:
                out[g.name] = f"{g.name}: its producer failed: {str(exc).strip()[:1000]}"
        return out
    order = sorted(groups, key=lambda g: -last_s.get(g.name, 0.0))
    with concurrent.futures.ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = {pool.submit(_compute_one, g.name): g.name for g in order}
        for done in concurrent.futures.as_completed(futures):
            try:
                out.update(done.result())
            except (*failures, concurrent.futures.process.BrokenProcessPool) as exc:
                out[futures[done]] = f"{futures[done]}: its producer failed: {str(exc).strip()[:1000]}"
    return {g.name: out[g.name] for g in groups}  # the file's order, not the finishing order


def last_durations(data: dict) -> dict[str, float]:
    """Each group's duration when last computed (s), from its provenance."""
    return {name: float(g.get("provenance", {}).get("duration_s", 0.0)) for name, g in data.get("groups", {}).items()}


def load() -> dict:
    if not FIGURES_FILE.exists():
        return {"groups": {}}
    return json.loads(FIGURES_FILE.read_text())


def save(data: dict) -> None:
    FIGURES_FILE.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")


def figure(data: dict, key: str) -> Figure:
    group, _, name = key.partition(".")
    try:
        return Figure(**data["groups"][group]["figures"][name])
    except KeyError:
        raise KeyError(f"no figure {key!r} in docs/{FIGURES_FILE.name}") from None


def render_table(data: dict, name: str) -> str:
    """``GROUP-TABLE`` as a Markdown table (or ``GROUP-BLOCK`` as a code block) with its provenance."""
    group, _, table = name.partition("-")
    g = data["groups"].get(group, {})
    prov = g.get("provenance")
    if table in g.get("tables", {}):
        rows = g["tables"][table]
        lines = ["| " + " | ".join(rows[0]) + " |", "|" + "---|" * len(rows[0])]
        lines += ["| " + " | ".join(r) + " |" for r in rows[1:]]
        body = "\n".join(lines) + "\n"
    elif table in g.get("blocks", {}):
        body = "```\n" + g["blocks"][table] + "```\n"
    else:
        raise KeyError(f"no table or block {name!r} in {FIGURES_FILE.relative_to(ROOT)}")
    return body + (
        f"\n<sub>`python tools/figures.py --only {group}` at {prov['commit'][:10]}, {prov['date'][:10]}, "
        f"{prov['duration_s']:.0f} s: `{'`; `'.join(prov['commands'])}`</sub>\n"
    )


def release_check_text(data: dict) -> str:
    """The release check's record as the docs show it."""
    r = data.get("release_check")
    if not r:
        return ("never run against this figures file: run `python tools/figures.py --check --all` before a "
                "release")
    return (f"`python tools/figures.py --check --all` on {r['date'][:10]} at {r['commit'][:10]}: "
            f"{len(r['groups'])} groups recomputed in {r['duration_s']:.0f} s, {len(r.get('agreed', []))} of "
            f"them agree with the file: {r['result']}")


def _release_digest(r: dict) -> str:
    content = json.dumps({k: v for k, v in r.items() if k != "digest"}, sort_keys=True)
    return hashlib.sha256(content.encode()).hexdigest()


def render_text(text: str, data: dict) -> str:
    def fig(m):
        try:
            return f"<!-- fig:{m['key']} -->{figure(data, m['key']).text()}<!-- /fig -->"
        except KeyError:  # not computed yet: left as it is, and --check names it
            return m[0]

    def table(m):
        try:
            return m["open"] + render_table(data, m["name"]) + m["close"]
        except KeyError:
            return m[0]

    text = CHECK_MARK.sub(lambda m: f"<!-- figcheck -->{release_check_text(data)}<!-- /figcheck -->", text)
    return TABLE_MARK.sub(table, FIG_MARK.sub(fig, text))


def disagreements(data: dict, computing: frozenset[str] = frozenset()) -> list[str]:
    """Where a published document says something other than the figures file (the groups being
    computed, ``computing``, are left out: the suite runs inside ``test_suite``'s measurement)."""
    out = []
    for path in PUBLISHED:
        text = path.read_text()
        for m in FIG_MARK.finditer(text):
            if m["key"].partition(".")[0] in computing:
                continue
            line = text.count("\n", 0, m.start()) + 1
            try:
                want = figure(data, m["key"]).text()
            except KeyError as e:
                out.append(f"{path.relative_to(ROOT)}:{line}: {e.args[0]}")
                continue
            if m["text"] != want:
                out.append(
                    f"{path.relative_to(ROOT)}:{line}: {m['key']} reads {m['text']!r}, the figures file {want!r}"
                )
        for m in TABLE_MARK.finditer(text):
            if m["name"].partition("-")[0] in computing:
                continue
            line = text.count("\n", 0, m.start()) + 1
            try:
                want = render_table(data, m["name"])
            except KeyError as e:
                out.append(f"{path.relative_to(ROOT)}:{line}: {e.args[0]}")
                continue
            if m["body"] != want:
                out.append(f"{path.relative_to(ROOT)}:{line}: table {m['name']} differs from the figures file")
        for m in CHECK_MARK.finditer(text):
            if m["text"] != release_check_text(data):
                line = text.count("\n", 0, m.start()) + 1
                out.append(f"{path.relative_to(ROOT)}:{line}: the release check's record differs from the figures file")
    release = data.get("release_check")
    if release and release.get("digest") != _release_digest(release):
        out.append(f"{FIGURES_FILE.name}: release_check: not what tools/figures.py wrote (digest mismatch)")
    return out


#: a decimal number in prose or a table (what ``unmarked_numbers`` counts)
DECIMAL = re.compile(r"(?<![\w.])\d+\.\d+(?![\w.])")
#: the requirement registry's generated tables (hil/verdicts/requirements.py): limits and sources, not measurements
GENERATED_MARK = re.compile(r"<!-- generated from hil/verdicts/requirements\.py.*?<!-- end of the generated table -->",
                            re.S)


def unmarked_numbers(text: str) -> list[tuple[int, str]]:
    """(line, number) of every decimal outside the figure markers and the registry's generated tables:
    parameters, the paper's values, limits, and measurements not yet under a marker."""
    blank = lambda m: "\n" * m[0].count("\n")  # noqa: E731 - keep line numbers
    for mark in (FIG_MARK, TABLE_MARK, CHECK_MARK, GENERATED_MARK):
        text = mark.sub(blank, text)
    return [(text.count("\n", 0, m.start()) + 1, m[0]) for m in DECIMAL.finditer(text)]


def unmarked_counts() -> dict[str, int]:
    return {str(p.relative_to(ROOT)): len(unmarked_numbers(p.read_text())) for p in PUBLISHED}


def unmarked_growth(data: dict) -> list[str]:
    """Pages with more unmarked decimals than the file's ledger allows (the ledger only shrinks)."""
    ledger = data.get("unmarked_ledger", {})
    return [f"{page}: {n} decimals outside the figure markers, the ledger allows {ledger.get(page, 0)}: put a "
            "measurement under a marker (tools/figures.py), or remove it"
            for page, n in unmarked_counts().items() if n > ledger.get(page, 0)]


def render(data: dict) -> list[Path]:
    changed = []
    for path in PUBLISHED:
        old = path.read_text()
        new = render_text(old, data)
        if new != old:
            path.write_text(new)
            changed.append(path)
    return changed


NUMBER = re.compile(r"[-+\u2212]?\d+(?:\.\d+)?(?:e[-+]?\d+)?")


def _cell_drift(old: str, new: str, rel: float) -> str | None:
    """Why cell ``new`` is not cell ``old``: the words must be the same and every number within the
    larger of ``rel`` of it and one unit of its last printed digit."""
    if old == new:
        return None
    if NUMBER.sub("#", old) != NUMBER.sub("#", new):
        return f"{old!r} -> {new!r}"
    for a, b in zip(NUMBER.findall(old), NUMBER.findall(new)):
        x, y = float(a.replace("\u2212", "-")), float(b.replace("\u2212", "-"))
        digits = len(a.split(".")[1].split("e")[0]) if "." in a else 0
        if abs(y - x) > max(rel * abs(x), 10.0 ** -digits) + 1e-12:
            return f"{old!r} -> {new!r}"
    return None


#: how far a recomputed table cell may move (relative; at least one unit of its last digit)
TABLE_TOLERANCE_REL = 0.03


def _tables_drift(gname: str, old: dict, new: dict) -> list[str]:
    out = []
    for kind in ("tables", "blocks"):
        for name, rows in new.get(kind, {}).items():
            if name not in old.get(kind, {}):
                out.append(f"{gname}-{name}: new {kind[:-1]}, not in the file")
                continue
            was = old[kind][name]
            if kind == "blocks":
                rows, was = [[line] for line in rows.splitlines()], [[line] for line in was.splitlines()]
            if len(rows) != len(was) or any(len(a) != len(b) for a, b in zip(rows, was)):
                out.append(f"{gname}-{name}: {kind[:-1]} shape {len(was)} rows -> {len(rows)} rows")
                continue
            for i, (ra, rb) in enumerate(zip(was, rows)):
                for j, (a, b) in enumerate(zip(ra, rb)):
                    why = _cell_drift(a, b, TABLE_TOLERANCE_REL)
                    if why:
                        out.append(f"{gname}-{name}: row {i} column {j}: {why}")
        for name in old.get(kind, {}):
            if name not in new.get(kind, {}):
                out.append(f"{gname}-{name}: no longer computed")
    return out


def digest(group: dict) -> str:
    """What the tool wrote for a group, hashed: its figures, tables, blocks and provenance."""
    content = {k: group.get(k) for k in ("figures", "tables", "blocks", "provenance")}
    return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()


def _git(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True)


def history_note() -> str | None:
    """Why provenance commits cannot be checked here (no git, a clone without history), or None."""
    try:
        inside = _git("rev-parse", "--is-inside-work-tree")
    except FileNotFoundError:
        return "provenance NOT checked: git is not installed"
    if inside.returncode != 0:
        return "provenance NOT checked: not a git checkout (an archive has no history to check commits against)"
    if _git("rev-parse", "--is-shallow-repository").stdout.strip() == "true":
        return ("provenance NOT checked: this clone has no history (shallow); `git fetch --unshallow` "
                "and check again")
    return None


def _not_an_ancestor(commit: str) -> str | None:
    """Why ``commit`` is not an ancestor of HEAD in this repository, or None (history assumed: see
    :func:`history_note`)."""
    if not re.fullmatch(r"[0-9a-f]{40}", commit):
        return f"{commit!r} is not a commit"
    if _git("cat-file", "-e", f"{commit}^{{commit}}").returncode != 0:
        return f"{commit[:12]} is no commit of this repository"
    if _git("merge-base", "--is-ancestor", commit, "HEAD").returncode != 0:
        return f"{commit[:12]} is not an ancestor of HEAD"
    return None


def _glob_regex(glob: str) -> re.Pattern:
    """A path glob of :attr:`Group.inputs`: ``**`` spans directories, ``*`` and ``?`` stay within a name."""
    parts = re.split(r"(\*\*|\*|\?)", glob)
    wild = {"**": ".*", "*": "[^/]*", "?": "[^/]"}
    return re.compile("".join(wild.get(x, re.escape(x)) for x in parts) + r"\Z")


def matching(paths: list[str], globs: tuple[str, ...]) -> list[str]:
    """The paths a group's inputs name (``!glob`` takes paths out again)."""
    keep = [_glob_regex(g) for g in globs if not g.startswith("!")]
    drop = [_glob_regex(g[1:]) for g in globs if g.startswith("!")]
    return [p for p in paths if any(k.match(p) for k in keep) and not any(d.match(p) for d in drop)]


def changed_since(commit: str) -> list[str]:
    """Every path that differs between ``commit`` and the working tree: changed in later commits,
    staged or not, and untracked files git does not ignore."""
    diff = _git("diff", "--name-only", "--no-renames", "-z", commit, "--")
    if diff.returncode != 0:
        raise RuntimeError(f"git diff {commit}: {diff.stderr.strip()}")
    untracked = _git("ls-files", "--others", "--exclude-standard", "-z").stdout
    return sorted((set(diff.stdout.split("\0")) | set(untracked.split("\0"))) - {""})


def stale_groups(data: dict) -> dict[str, str]:
    """The file's groups that cannot pass ``--check`` unless recomputed, and why: their provenance
    commit is not an ancestor of HEAD (or this checkout cannot tell), or one of their declared inputs
    changed since it. A group whose commit and inputs say nothing changed is not recomputed: the check
    then holds its content (digest) and the docs to the file, and only a recompute (the CI rotation,
    the release check) would see a figure rewritten with a commit after its last input change."""
    note = history_note()
    declared = {g.name: g for g in GROUPS}
    changes: dict[str, list[str]] = {}
    out = {}
    for name, g in data.get("groups", {}).items():
        if name not in declared:
            continue  # provenance_problems names it; there is nothing to recompute it with
        commit = str((g.get("provenance") or {}).get("commit", ""))
        why = note or _not_an_ancestor(commit)
        if why:
            out[name] = why if note else f"provenance commit {why}"
            continue
        if commit not in changes:
            changes[commit] = changed_since(commit)
        hit = matching(changes[commit], declared[name].inputs)
        if hit:
            out[name] = (f"{len(hit)} of its inputs changed since {commit[:10]} ({', '.join(hit[:3])}"
                         + (", ...)" if len(hit) > 3 else ")"))
    return out


def rotation_group() -> Group:
    """The slow group this commit's CI run recomputes (``rotation=True``): the next one per commit,
    counted along HEAD's history, so each is recomputed once in any run of that many commits; in a
    clone without history, HEAD's hash picks it."""
    rotating = [g for g in GROUPS if g.rotation]
    count = _git("rev-list", "--count", "HEAD").stdout.strip()
    n = int(count) if history_note() is None and count.isdigit() else int(_git("rev-parse", "HEAD").stdout, 16)
    return rotating[n % len(rotating)]


def provenance_problems(data: dict) -> list[str]:
    """Groups whose content is not what the tool wrote (digest) or whose commit is not HEAD's ancestor;
    commits are not looked at when :func:`history_note` says this checkout cannot show them."""
    out = []
    note = history_note()
    declared = {g.name for g in GROUPS}
    for name, g in data.get("groups", {}).items():
        prov = g.get("provenance") or {}
        if name not in declared:  # nothing would ever recompute it
            out.append(f"{FIGURES_FILE.name}: group {name}: no such group in tools/figures.py")
        if g.get("digest") != digest(g):
            out.append(f"{FIGURES_FILE.name}: group {name}: its content is not what tools/figures.py wrote "
                       f"(digest mismatch: edited by hand?); recompute it: python tools/figures.py --only {name}")
        if not prov.get("commands") or not prov.get("date"):
            out.append(f"{FIGURES_FILE.name}: group {name}: provenance without commands or date")
        commit = str(prov.get("commit", ""))
        if not re.fullmatch(r"[0-9a-f]{40}", commit):
            out.append(f"{FIGURES_FILE.name}: group {name}: provenance commit {commit!r} is not a commit "
                       "(computed from uncommitted files is not reproducible: commit, then compute)")
            continue
        if note is None and (why := _not_an_ancestor(commit)):
            out.append(f"{FIGURES_FILE.name}: group {name}: provenance commit {why}")
    release = data.get("release_check")
    if release and note is None and (why := _not_an_ancestor(str(release.get("commit", "")))):
        out.append(f"{FIGURES_FILE.name}: release_check: commit {why}")
    return out


def drift(stored: dict, fresh: dict) -> list[str]:
    """Where recomputed groups differ from the file: figures beyond their tolerance, table and block
    cells beyond ``TABLE_TOLERANCE_REL`` (words exactly)."""
    out = []
    for gname, g in fresh.items():
        old = stored["groups"].get(gname)
        if old is None:
            out.append(f"{gname}: not in {FIGURES_FILE.relative_to(ROOT)}")
            continue
        for name, f in g["figures"].items():
            if name not in old["figures"]:
                out.append(f"{gname}.{name}: new figure, not in the file")
                continue
            why = Figure(**old["figures"][name]).drift(Figure(**f))
            if why:
                out.append(f"{gname}.{name}: {why}")
        for name in old["figures"]:
            if name not in g["figures"]:
                out.append(f"{gname}.{name}: no longer computed")
        out += _tables_drift(gname, old, g)
    return out


def _recompute_and_compare(data: dict, chosen: list[Group], jobs: int = 1) -> dict[str, list[str]]:
    """Each chosen group recomputed and compared with the file: its differences (none: it agrees); a
    producer that fails is a difference, and the others still run."""
    fresh = compute_each(chosen, jobs, last_durations(data))
    return {name: [entry] if isinstance(entry, str) else drift(data, {name: entry}) for name, entry in fresh.items()}


def _record_release_check(data: dict, chosen: list[Group], differ: dict[str, list[str]], duration_s: float,
                          jobs: int = 1, commit: str | None = None) -> None:
    """``--check --all``: the record the docs show (README.md, "Published figures"), kept in the file;
    ``commit``: the code checked, as the check began (default: HEAD now)."""
    record = {
        "date": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "commit": commit or _commit(),
        "groups": [g.name for g in chosen],
        "agreed": [name for name, lines in differ.items() if not lines],
        "duration_s": round(duration_s, 1),
        "jobs": max(jobs, 1),
    }
    record["result"] = ("every figure and table cell within tolerance" if len(record["agreed"]) == len(chosen)
                        else f"{len(chosen) - len(record['agreed'])} groups differ: "
                        + ", ".join(name for name, lines in differ.items() if lines))
    record["digest"] = _release_digest(record)
    data["release_check"] = record
    save(data)
    render(data)


def check(data: dict, only: list[str] | None = None, every: bool = False, jobs: int = 1) -> int:
    """``--check``: the docs against the file, each group's digest and commit, and every group that
    cannot pass without it recomputed (:func:`stale_groups`), or the groups named (``only``), or all
    of them (``every``: the release check, whose record the file keeps and README.md shows)."""
    bad = disagreements(data) + provenance_problems(data) + unmarked_growth(data)
    note = history_note()
    if note:
        print(f"figures: {note}")
    stale = stale_groups(data)
    published = [g for g in GROUPS if g.name in data.get("groups", {})]
    chosen = published if every else [g for g in published if (g.name in only if only else g.name in stale)]
    for g in GROUPS:
        if g.name not in data.get("groups", {}):
            print(f"figures: {g.name}: never computed, nothing of it is published")
        elif g.name in stale:
            print(f"figures: {g.name}: {stale[g.name]}: "
                  + ("recomputing" if g in chosen else "NOT recomputed here (outside --only)"), flush=True)
    t0 = time.perf_counter()
    checked = _commit()  # the code checked, taken before the groups run (a run may touch files)
    differ = _recompute_and_compare(data, chosen, jobs)
    bad += [line for lines in differ.values() for line in lines]
    if every:
        _record_release_check(data, chosen, differ, time.perf_counter() - t0, jobs, checked)
    unchecked = sorted(set(stale) - {g.name for g in chosen})
    if bad:
        print("\n".join(bad))
    elif unchecked:
        print(f"figures: the {len(chosen)} groups recomputed agree with {FIGURES_FILE.name}; NOT checked: "
              f"{', '.join(unchecked)} (their inputs changed: `python tools/figures.py --check` recomputes them)")
    else:
        print(f"figures: every published figure agrees with {FIGURES_FILE.name} ({len(chosen)} groups "
              f"recomputed{': ' + ', '.join(g.name for g in chosen) if chosen else ''})")
    return 1 if bad else 0


# ---------------------------------------------------------------- the command line


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--quick", action="store_true", help="recompute the quick subset; exit 1 on drift")
    mode.add_argument("--render", action="store_true", help="rewrite the docs from the figures file")
    mode.add_argument("--check", action="store_true",
                      help="exit 1 where a doc disagrees with the figures file, a group is not what the tool wrote "
                           "or its commit is not an ancestor of HEAD, or a group recomputed differs; recomputes "
                           "every group whose declared inputs changed since its commit (see --stale)")
    mode.add_argument("--stale", action="store_true",
                      help="list the groups --check would recompute, and why (nothing is computed)")
    ap.add_argument("--only", nargs="+", metavar="GROUP", choices=[g.name for g in GROUPS],
                    help="compute (or with --check, recompute and compare) these groups only")
    ap.add_argument("--all", action="store_true",
                    help="with --check: recompute every group and compare figures and table cells (the release "
                         "check; its record is kept in the file and shown in README.md)")
    ap.add_argument("-j", "--jobs", type=int, default=1, metavar="N",
                    help="compute (or recompute) N groups at once, each in a process of its own, the longest "
                         "first (default 1; the figures do not depend on it, the groups' wall times do)")
    mode.add_argument("--unmarked", action="store_true",
                      help="list every decimal of README.md and docs/ outside a figure marker, lower the ledger "
                           "where a page has fewer (exit 1 where a page has more)")
    return ap


def _list_unmarked(data: dict) -> int:
    """``--unmarked``: every decimal outside the markers, the ledger lowered where a page has fewer."""
    for path in PUBLISHED:
        for line, number in unmarked_numbers(path.read_text()):
            print(f"{path.relative_to(ROOT)}:{line}: {number}")
    counts, ledger = unmarked_counts(), data.setdefault("unmarked_ledger", {})
    grew = unmarked_growth(data)
    lowered = {page: n for page, n in counts.items() if n < ledger.get(page, 0)}
    if lowered:  # the ledger only shrinks
        ledger.update(lowered)
        save(data)
    print("\n".join(grew) + "\n" if grew else "", end="")
    print(f"figures: {sum(counts.values())} decimals outside the markers; the ledger allows "
          f"{sum(ledger.values())}" + (f" (lowered on {', '.join(sorted(lowered))})" if lowered else ""))
    return 1 if grew else 0


def _list_stale(data: dict) -> int:
    """``--stale``: the groups ``--check`` would recompute, why, and how long they took last."""
    durations = {name: g["provenance"]["duration_s"] for name, g in data.get("groups", {}).items()}
    stale = stale_groups(data)
    for name, why in stale.items():
        print(f"{name}: {why} (last computed in {durations[name]:.0f} s)")
    print(f"figures: {len(stale)} of {len(durations)} groups to recompute (they took "
          f"{sum(durations[n] for n in stale):.0f} s when last computed)")
    return 0


def _render_pages(data: dict) -> int:
    for p in render(data):
        print(f"rendered {p.relative_to(ROOT)}")
    return 0


def _compute_and_write(data: dict, chosen: list[Group], quick: bool, jobs: int = 1) -> int:
    """Compute the chosen groups; ``quick``: compare them with the file (exit 1 on drift), otherwise
    write them into the file and render the pages."""
    t0 = time.perf_counter()
    if jobs > 1:
        each = compute_each(chosen, jobs, last_durations(data))
        failed = [entry for entry in each.values() if isinstance(entry, str)]
        if failed:  # nothing written: the file keeps only what one run of the tool computed in full
            print("\n".join(failed))
            return 1
        fresh = {name: entry for name, entry in each.items() if not isinstance(entry, str)}
    else:
        fresh = compute(chosen)
    if quick:
        bad = drift(data, fresh)
        print("\n".join(bad) if bad else f"figures: {len(chosen)} quick groups reproduce within tolerance "
                                            f"({time.perf_counter() - t0:.0f} s)")
        return 1 if bad else 0
    data = load()  # as it is now: another run may have written its groups meanwhile
    data.setdefault("groups", {}).update(fresh)
    save(data)
    _render_pages(data)
    print(f"figures: wrote {FIGURES_FILE.relative_to(ROOT)} ({time.perf_counter() - t0:.0f} s)")
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = _parser()
    args = ap.parse_args(argv)
    if args.all and not args.check:
        ap.error("--all goes with --check (plain `python tools/figures.py` computes every group)")
    if args.jobs < 1:
        ap.error(f"-j {args.jobs}: give a number of groups at once, 1 or more")
    data = load()
    if args.unmarked:
        return _list_unmarked(data)
    if args.check:
        return check(data, args.only, args.all, args.jobs)
    if args.stale:
        return _list_stale(data)
    if args.render:
        return _render_pages(data)
    if args.only:
        chosen = [g for g in GROUPS if g.name in args.only]
    else:
        chosen = [g for g in GROUPS if g.quick or not args.quick]
    return _compute_and_write(data, chosen, args.quick, args.jobs)
