"""Sources a firmware folder fetches instead of holding: the ``[fetch]`` table of a ``sil.toml``.

Someone else's code is named, never copied: the repository's git URL, one commit, and each file
taken from it with its git blob (the sha1 ``git hash-object`` prints), as Zephyr's west and CMake's
FetchContent pin theirs. Where the files come from, the first that applies:

- ``HIL_SIL_SOURCES``: a local checkout of the repository (any commit whose files have the blobs
  listed; nothing is fetched);
- the cache (the build cache's ``sources/KEY``: ``hil.sil.build.fetch_sources``), from an earlier run;
- ``git``: the one commit fetched shallow (``git fetch --depth 1 URL COMMIT``) into a temporary
  repository that is removed afterwards.

Every file is checked against its blob wherever it came from, the cache included, and the build
sees only the listed files, each at its path in the repository (so the sources' relative
``#include``s resolve as upstream). A wrong blob is one line naming the file, the blob expected
and the blob found; a fetch that cannot reach the URL is one line naming it
(``SourcesUnavailable``, which a test of a fetched example skips on, naming it).
"""

from __future__ import annotations

import glob
import hashlib
import os
import re
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from bldc.tomlfile import TomlError


#: the environment variable naming a local checkout to take the files from
CHECKOUT_ENV = "HIL_SIL_SOURCES"
_HEX40 = re.compile(r"[0-9a-f]{40}")
#: what git (its curl or ssh) says when the network, not the request, failed
_NO_NETWORK = ("could not resolve", "failed to connect", "timed out", "connection refused", "network is unreachable",
               "unable to access", "could not read from remote", "no route to host", "does not appear to be a git")
#: wall time a fetch may take (a stalled transfer is cut earlier: http.lowSpeedTime below)
FETCH_TIMEOUT_S = 600


class SourcesError(RuntimeError):
    """Sources that cannot be used: a file not in the repository, or not the blob listed."""


class SourcesUnavailable(SourcesError):
    """The files could not be had: no checkout given and the repository could not be reached."""


@dataclass(frozen=True)
class FetchSpec:
    """A ``sil.toml``'s ``[fetch]`` table, read strictly."""

    where: str  #: the sil.toml, for messages
    url: str
    commit: str
    files: tuple[tuple[str, str], ...]  #: (path in the repository, git blob)
    sources: tuple[str, ...] = ()  #: globs over the files, compiled with the folder's own
    include: tuple[str, ...] = ()  #: folders of the fetched tree on the include path

    @property
    def key(self) -> str:
        """The cache folder's name: the commit and a digest of the files and their blobs."""
        digest = hashlib.sha256(repr((self.url, self.files)).encode()).hexdigest()[:12]
        return f"{self.commit[:12]}-{digest}"


def git_blob(data: bytes) -> str:
    """The git blob id of ``data``: what ``git hash-object`` prints for a file holding it."""
    return hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest()


def read_fetch(table, where: str) -> FetchSpec:
    """``[fetch]`` of the sil.toml ``where`` (its keys are checked by the file's schema)."""

    def fail(key: str, message: str):
        return TomlError(where, message, table="[fetch]", key=key)

    if not isinstance(table, dict):
        raise TomlError(where, f"must be a table, got {table!r}", key="fetch")
    url = table.get("url")
    if not isinstance(url, str) or not url.strip():
        raise fail("url", f"required: the repository's git URL, got {url!r}")
    commit = table.get("commit")
    if not isinstance(commit, str) or not _HEX40.fullmatch(commit):
        raise fail("commit", f"a commit's full 40-digit hex id (a branch or tag moves), got {commit!r}")
    files = table.get("files")
    if not isinstance(files, dict) or not files:
        raise fail("files", "required: a table of path = git blob, one per file taken")
    for path, blob in files.items():
        parts = PurePosixPath(path).parts
        if path.startswith("/") or "\\" in path or ".." in parts or not parts:
            raise TomlError(where, "a relative path inside the repository", table="[fetch.files]", key=path)
        if not isinstance(blob, str) or not _HEX40.fullmatch(blob):
            raise TomlError(where, f"the file's git blob (40 hex digits, git hash-object), got {blob!r}",
                            table="[fetch.files]", key=path)
    lists = {}
    for key in ("sources", "include"):
        value = table.get(key, [])
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise fail(key, f"must be a list of strings, got {value!r}")
        lists[key] = tuple(value)
    return FetchSpec(where, url.strip(), commit, tuple(sorted(files.items())), **lists)


def fetched_tree(fetch: FetchSpec, cache: Path) -> tuple[Path, str]:
    """The folder holding ``fetch``'s files (in ``cache``), each checked against its blob, and one
    line on where they came from."""
    tree = cache / fetch.key
    checkout = os.environ.get(CHECKOUT_ENV)
    if checkout:
        how = f"{CHECKOUT_ENV}={checkout}"
        files = _from_checkout(fetch, Path(checkout), how)
    elif _intact(fetch, tree):
        return tree, f"{fetch.url} at {fetch.commit[:12]} (cached)"
    else:
        how = "fetched"
        files = _from_git(fetch, f"{fetch.url} at {fetch.commit}")
    if not _intact(fetch, tree):
        _store(tree, files)
    return tree, f"{fetch.url} at {fetch.commit[:12]} ({how})"


def _check(fetch: FetchSpec, path: str, data: bytes, origin: str) -> bytes:
    expected = dict(fetch.files)[path]
    found = git_blob(data)
    if found != expected:
        raise SourcesError(f"{fetch.where}: [fetch.files].{path}: expected blob {expected}, found {found} ({origin})")
    return data


def _from_checkout(fetch: FetchSpec, checkout: Path, origin: str) -> dict[str, bytes]:
    if not checkout.is_dir():
        raise SourcesError(f"{fetch.where}: [fetch]: {origin}: no such folder (a checkout of {fetch.url})")
    files = {}
    for path, _ in fetch.files:
        try:
            files[path] = _check(fetch, path, (checkout / path).read_bytes(), origin)
        except OSError as exc:
            raise SourcesError(f"{fetch.where}: [fetch.files].{path}: cannot read it in {origin}: "
                                f"{exc.strerror or exc}") from None
    return files


def _git(args: list[str], cwd: str, what: str, fetch: FetchSpec) -> subprocess.CompletedProcess:
    env = {**os.environ, "GIT_TERMINAL_PROMPT": "0", "GIT_ASKPASS": "", "SSH_ASKPASS": ""}
    try:
        return subprocess.run(["git", *args], cwd=cwd, capture_output=True, env=env, timeout=FETCH_TIMEOUT_S)
    except FileNotFoundError:
        raise SourcesUnavailable(f"{fetch.where}: [fetch]: git is not installed to fetch {fetch.url}, and "
                                 f"{CHECKOUT_ENV} names no checkout of it") from None
    except subprocess.TimeoutExpired:
        raise SourcesUnavailable(f"{fetch.where}: [fetch]: {what} {fetch.url} gave no answer within {FETCH_TIMEOUT_S} "
                                 f"s; without network, set {CHECKOUT_ENV} to a checkout of it") from None


def _reason(out: bytes) -> str:
    """git's one line on why it failed: its first ``fatal:`` line (advice follows it), else its last."""
    lines = [line.strip() for line in out.decode(errors="replace").splitlines() if line.strip()]
    return next((line for line in lines if line.startswith("fatal:")), lines[-1] if lines else "no message")


def _from_git(fetch: FetchSpec, origin: str) -> dict[str, bytes]:
    with tempfile.TemporaryDirectory(prefix="hil-sil-fetch-") as tmp:
        _git(["init", "-q"], tmp, "git init for", fetch)
        # the one commit, shallow; a transfer slower than 1 kB/s for 60 s is cut
        got = _git(["-c", "http.lowSpeedLimit=1000", "-c", "http.lowSpeedTime=60", "fetch", "-q", "--depth", "1",
                    "--no-tags", fetch.url, fetch.commit], tmp, "fetching", fetch)
        if got.returncode != 0:
            why = _reason(got.stderr)
            if any(phrase in got.stderr.decode(errors="replace").lower() for phrase in _NO_NETWORK):
                raise SourcesUnavailable(f"{fetch.where}: [fetch]: cannot fetch {fetch.url}: {why}; without "
                                         f"network, set {CHECKOUT_ENV} to a checkout of it")
            raise SourcesError(f"{fetch.where}: [fetch]: fetching {fetch.commit} from {fetch.url} failed: {why}")
        files = {}
        for path, _ in fetch.files:
            blob = _git(["cat-file", "blob", f"FETCH_HEAD:{path}"], tmp, "reading", fetch)
            if blob.returncode != 0:
                raise SourcesError(f"{fetch.where}: [fetch.files].{path}: not in {origin}")
            files[path] = _check(fetch, path, blob.stdout, origin)
    return files


def _intact(fetch: FetchSpec, tree: Path) -> bool:
    """Whether the cached tree holds exactly the listed files with their blobs (one that does not
    is removed: it is fetched again)."""
    if not tree.is_dir():
        return False
    present = {p.relative_to(tree).as_posix() for p in tree.rglob("*") if p.is_file()}
    if present == {path for path, _ in fetch.files} and all(
        git_blob((tree / path).read_bytes()) == blob for path, blob in fetch.files
    ):
        return True
    shutil.rmtree(tree, ignore_errors=True)
    return False


def _store(tree: Path, files: dict[str, bytes]) -> None:
    tree.parent.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=f"{tree.name}-", dir=tree.parent))
    try:
        for path, data in files.items():
            (work / path).parent.mkdir(parents=True, exist_ok=True)
            (work / path).write_bytes(data)
        try:
            os.rename(work, tree)  # atomic: a concurrent run either wins or finds ours
        except OSError:
            if not tree.is_dir():
                raise
    finally:
        shutil.rmtree(work, ignore_errors=True)


def expand(fetch: FetchSpec, tree: Path, suffixes: tuple[str, ...]) -> tuple[tuple[Path, ...], tuple[Path, ...]]:
    """The fetched sources (``fetch.sources`` globbed in ``tree``; each must end in one of
    ``suffixes``) and include folders."""
    sources: list[Path] = []
    for pattern in fetch.sources:
        matched = sorted(glob.glob(str(tree / pattern), recursive=True))
        if not matched:
            raise TomlError(fetch.where, f"{pattern!r} matches none of the files taken", table="[fetch]",
                            key="sources")
        for m in map(Path, matched):
            if m.suffix not in suffixes:
                raise TomlError(fetch.where, f"{m.relative_to(tree)}: not a C (.c) or C++ (.cc, .cpp, .cxx) source",
                                table="[fetch]", key="sources")
            if m not in sources:
                sources.append(m)
    include = []
    for d in fetch.include:
        if not (tree / d).is_dir():
            raise TomlError(fetch.where, f"{d!r}: no folder of the files taken", table="[fetch]", key="include")
        include.append(tree / d)
    return tuple(sources), tuple(include)
