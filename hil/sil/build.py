"""Build a firmware folder (``sil.toml``, ``hil-sil-build/1``) into a shared library, cached.

The compiler: ``HIL_SIL_CC`` / ``HIL_SIL_CXX`` when set (a command line), else the system's ``cc``
and ``c++`` when on PATH, else Zig's clang from the ``ziglang`` wheel (``python -m ziglang cc``),
which installs with pip, so a machine with only Python and pip builds firmware too. C sources are
C99, C++ sources C++17, unless the file's ``flags`` give a ``-std`` of that language.

The cache: one folder per key, the key a SHA-256 of the compiler (its command and version), every
source and header the build can see (the listed sources, every file under the include folders and
the framework's ``hil_sil.h``), the defines, the flags and the extra defines of the DUT string. A
changed source or setting rebuilds; an unchanged one does not. ``HIL_SIL_CACHE`` moves the cache
(default ``~/.cache/bldc-hil/sil``).
"""

from __future__ import annotations

import functools
import glob
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from bldc.tomlfile import TomlError, load_toml

FORMAT = "hil-sil-build/1"
#: the framework's own header folder, on every build's include path (``#include "hil_sil.h"``)
HEADER_DIR = Path(__file__).resolve().parent / "include"
C_SUFFIXES = (".c",)
CXX_SUFFIXES = (".cc", ".cpp", ".cxx")
HEADER_SUFFIXES = (".h", ".hh", ".hpp", ".hxx", ".inc", ".inl")
#: ``target`` is processor in the loop's (``hil.pil.target``): accepted here and ignored
_SCHEMA = {"format": None, "sources": None, "include": None, "defines": None, "flags": None, "profile": None,
           "target": None}


class SilBuildError(RuntimeError):
    """A firmware that cannot be built; the message names the file, key or compiler output."""


@dataclass(frozen=True)
class BuildSpec:
    """A ``sil.toml``, read strictly."""

    path: Path  #: the sil.toml
    sources: tuple[Path, ...]
    include: tuple[Path, ...]
    defines: tuple[tuple[str, str], ...]  #: (NAME, VALUE); VALUE "" = -D NAME
    flags: tuple[str, ...]
    profile: Path | None

    @property
    def folder(self) -> Path:
        return self.path.parent


def read_build_spec(path: str | Path) -> BuildSpec:
    """The ``sil.toml`` at ``path`` (a folder holding one, or the file): unknown keys, a wrong
    format, a glob that matches nothing, a missing include folder are errors naming the file and key."""
    path = Path(path)
    if path.is_dir():
        path = path / "sil.toml"
    where = str(path)
    if not path.is_file():
        raise SilBuildError(f"{where}: no such file (a firmware folder holds a sil.toml)")
    data = load_toml(path, _SCHEMA)
    folder = path.parent.resolve()
    if data.get("format") != FORMAT:
        raise TomlError(where, f"must be {FORMAT!r}, got {data.get('format')!r}", key="format")

    def strings(key: str, required: bool = False) -> list[str]:
        value = data.get(key, [])
        if required and key not in data:
            raise TomlError(where, "required", key=key)
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise TomlError(where, f"must be a list of strings, got {value!r}", key=key)
        return value

    sources: list[Path] = []
    for pattern in strings("sources", required=True):
        matched = sorted(glob.glob(str(folder / pattern), recursive=True))
        if not matched:
            raise TomlError(where, f"{pattern!r} matches no file in {folder}", key="sources")
        for m in matched:
            p = Path(m).resolve()
            if p.suffix not in C_SUFFIXES + CXX_SUFFIXES:
                raise TomlError(where, f"{m}: not a C (.c) or C++ (.cc, .cpp, .cxx) source", key="sources")
            if p not in sources:
                sources.append(p)
    include = []
    for d in strings("include"):
        p = (folder / d).resolve()
        if not p.is_dir():
            raise TomlError(where, f"{d!r}: no such folder in {folder}", key="include")
        include.append(p)
    defines = data.get("defines", {})
    if not isinstance(defines, dict):
        raise TomlError(where, f"must be a table of NAME = value, got {defines!r}", key="defines")
    pairs = []
    for name, value in defines.items():
        if isinstance(value, bool) or not isinstance(value, (str, int)):
            raise TomlError(where, f"{name}: a string or an integer, got {value!r}", table="defines", key=name)
        pairs.append((name, str(value)))
    profile = data.get("profile")
    if profile is not None:
        if not isinstance(profile, str):
            raise TomlError(where, f"must be a file name, got {profile!r}", key="profile")
        profile = (folder / profile).resolve()
        if not profile.is_file():
            raise TomlError(where, f"{data['profile']!r}: no such file in {folder}", key="profile")
    return BuildSpec(path.resolve(), tuple(sources), tuple(include), tuple(pairs), tuple(strings("flags")), profile)


@dataclass(frozen=True)
class Toolchain:
    cc: tuple[str, ...]
    cxx: tuple[str, ...]
    version: str  #: what the C compiler says of itself (part of the cache key)
    origin: str  #: "HIL_SIL_CC", "system" or "ziglang"

    def describe(self) -> str:
        return f"{' '.join(self.cc)} ({self.origin}: {self.version})"


def _version(cmd: tuple[str, ...]) -> str:
    try:
        out = subprocess.run([*cmd, "--version"], capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise SilBuildError(f"the compiler {' '.join(cmd)} does not run: {exc}") from None
    if out.returncode != 0:
        raise SilBuildError(f"the compiler {' '.join(cmd)} does not run: {out.stderr.strip()[:300]}")
    return (out.stdout or out.stderr).strip().splitlines()[0]


@functools.lru_cache(maxsize=None)
def toolchain(prefer: str = "auto") -> Toolchain:
    """The compiler this machine has: ``prefer`` is ``auto`` (``HIL_SIL_CC``, else the system's,
    else ``ziglang``), ``system`` or ``ziglang``."""
    import shlex

    if prefer == "auto" and os.environ.get("HIL_SIL_CC"):
        cc = tuple(shlex.split(os.environ["HIL_SIL_CC"]))
        cxx = tuple(shlex.split(os.environ.get("HIL_SIL_CXX", ""))) or cc
        return Toolchain(cc, cxx, _version(cc), "HIL_SIL_CC")
    if prefer in ("auto", "system"):
        cc_path = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
        cxx_path = shutil.which("c++") or shutil.which("g++") or shutil.which("clang++")
        if cc_path and cxx_path:
            return Toolchain((cc_path,), (cxx_path,), _version((cc_path,)), "system")
        if prefer == "system":
            raise SilBuildError("no system C/C++ compiler on PATH (cc, c++)")
    try:
        import ziglang  # noqa: F401  (the wheel that carries Zig's clang)
    except ImportError:
        raise SilBuildError(
            "no C compiler: none on PATH and the ziglang package is not installed (python -m pip install ziglang)"
        ) from None
    cc = (sys.executable, "-m", "ziglang", "cc")
    cxx = (sys.executable, "-m", "ziglang", "c++")
    return Toolchain(cc, cxx, _version(cc), "ziglang")


def cache_root() -> Path:
    return Path(os.environ.get("HIL_SIL_CACHE") or Path.home() / ".cache" / "bldc-hil" / "sil")


def _std_flags(flags: tuple[str, ...], cxx: bool) -> list[str]:
    """The default standard of the language, unless ``flags`` give one of that language."""
    mine = [f for f in flags if f.startswith("-std=") and (("++" in f) == cxx)]
    return [] if mine else (["-std=c++17"] if cxx else ["-std=c99"])


def _language_flags(flags: tuple[str, ...], cxx: bool) -> list[str]:
    """``flags`` without a ``-std`` of the other language (one list serves C and C++ sources)."""
    return [f for f in flags if not (f.startswith("-std=") and (("++" in f) != cxx))]


def _key(spec: BuildSpec, tc: Toolchain, extra_defines: tuple[tuple[str, str], ...], salt: dict | None = None) -> str:
    """The cache key of a build; ``salt`` adds what another kind of build depends on (hil.pil.build:
    the core, the target's flags and memory sizes, its support files)."""
    h = hashlib.sha256()
    h.update(json.dumps({"format": FORMAT, "cc": tc.cc, "cxx": tc.cxx, "version": tc.version,
                         "defines": spec.defines, "extra": extra_defines, "flags": spec.flags,
                         "include": [str(p) for p in spec.include], **(salt or {})}, sort_keys=True).encode())
    files = set(spec.sources)
    for d in (*spec.include, HEADER_DIR):
        files |= {p for p in d.rglob("*") if p.is_file() and p.suffix in HEADER_SUFFIXES}
    # headers beside the sources (#include "x.h" from the source's own folder)
    for s in spec.sources:
        files |= {p for p in s.parent.iterdir() if p.is_file() and p.suffix in HEADER_SUFFIXES}
    for p in sorted(files):
        h.update(str(p).encode() + b"\0")
        h.update(p.read_bytes())
    return h.hexdigest()[:24]


@dataclass
class Built:
    library: Path
    key: str
    toolchain: str
    cached: bool
    log: list[str] = field(default_factory=list)


def build(spec: BuildSpec, extra_defines: tuple[tuple[str, str], ...] = (), prefer: str = "auto") -> Built:
    """The shared library of ``spec`` (built now, or taken from the cache)."""
    tc = toolchain(prefer)
    key = _key(spec, tc, extra_defines)

    def make(work: Path, log: list[str]) -> None:
        objects, any_cxx = [], False
        common = ["-fPIC", "-fvisibility=default", f"-I{HEADER_DIR}", *(f"-I{p}" for p in spec.include)]
        common += [f"-D{n}" if v == "" else f"-D{n}={v}" for n, v in (*spec.defines, *extra_defines)]
        for k, src in enumerate(spec.sources):
            cxx = src.suffix in CXX_SUFFIXES
            any_cxx |= cxx
            obj = work / f"{k:03d}-{src.stem}.o"
            cmd = [*(tc.cxx if cxx else tc.cc), *_std_flags(spec.flags, cxx), *common,
                   *_language_flags(spec.flags, cxx), "-c", str(src), "-o", str(obj)]
            _run(cmd, spec, log, f"compiling {src}")
            objects.append(str(obj))
        cmd = [*(tc.cxx if any_cxx else tc.cc), "-shared", *objects, "-o", str(work / "firmware.so"), "-lm"]
        _run(cmd, spec, log, "linking")

    library, cached, log = cached_build(key, "firmware.so", make)
    return Built(library, key, tc.describe(), cached, log)


def cached_build(key: str, product: str, make) -> tuple[Path, bool, list[str]]:
    """``cache_root() / key / product``: taken from the cache, or made by ``make(work, log)`` in a
    fresh folder that is then renamed into place (atomic: a concurrent build of the same key either
    wins or finds the other's). Returns the product, whether it was cached, and the commands run."""
    out_dir = cache_root() / key
    product_path = out_dir / product
    if product_path.is_file():
        return product_path, True, []
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=f"{key}-", dir=out_dir.parent))
    log: list[str] = []
    try:
        make(work, log)
        (work / "build.log").write_text("\n".join(log) + "\n")
        try:
            os.rename(work, out_dir)
        except OSError:
            if not product_path.is_file():
                raise
            shutil.rmtree(work, ignore_errors=True)
    except BaseException:
        shutil.rmtree(work, ignore_errors=True)
        raise
    return product_path, False, log


def _run(cmd: list[str], spec: BuildSpec, log: list[str], what: str) -> None:
    log.append(" ".join(cmd))
    try:
        out = subprocess.run(cmd, cwd=spec.folder, capture_output=True, text=True, timeout=600)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise SilBuildError(f"{spec.path}: {what}: the compiler failed to run: {exc}") from None
    if out.returncode != 0:
        text = (out.stderr or out.stdout).strip().splitlines()
        shown = "\n".join(text[:20]) + (f"\n... ({len(text) - 20} more lines)" if len(text) > 20 else "")
        raise SilBuildError(f"{spec.path}: {what} failed (exit {out.returncode}):\n{shown}")
