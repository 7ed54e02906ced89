"""``spark.compile``: DSL text → checked declaration → cached native module.

The text is checked with the macro's own parser (``_native.check_dsl``), so a
bad declaration fails with its line and column before cargo runs. A good one
becomes a small crate (``nonholonomic_system! { text }`` plus
``spark_python_core::export_system!``) that cargo builds into an extension
module, kept under ``<cache>/<key>/`` where the key hashes the text, the
spark version, the source tree and whether the module is optimized
(``optimize=False``, or ``SPARK_COMPILE_OPTIMIZE=0`` in the environment:
:func:`_optimized` decides). Loading a cached module needs no cargo.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import importlib.machinery
import importlib.util
import os
import re
import shutil
import subprocess
import sys
import threading
import tomllib
from dataclasses import dataclass
from pathlib import Path

from . import ArgumentError, DslError, SparkError, System, ToolchainError, _flag, _native, _short

_loaded: dict[str, System] = {}
_loading = threading.Lock()

TOOLCHAIN_HELP = (
    "spark.compile needs the Rust toolchain (cargo) to build the declaration into a native module, as "
    "CasADi's jit needs a C compiler. Install it with rustup (https://rustup.rs), make sure `cargo` is on "
    "PATH (or set CARGO to its path), and call spark.compile again. Registered systems (spark.system) "
    "need no toolchain."
)


def cache_root(cache_dir: str | None = None) -> Path:
    """Where compiled modules live: ``cache_dir`` (checked by
    :func:`_cache_dir`), ``SPARK_CACHE_DIR`` or ``~/.cache/spark-python``."""
    if cache_dir is not None:
        return Path(cache_dir)
    from_environment = _environment_cache_dir()
    if from_environment is not None:
        return Path(from_environment)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "spark-python"


#: The requests and results a module exchanges with this package (part of
#: the cache key): a module cached before a change to them would ignore the
#: new request keys (``rtol``, ``t_eval``, ``events`` of ``integrate`` and
#: of ``ensemble``) and run something else than asked. Raise it whenever
#: they change.
MODULE_INTERFACE = "3: rtol, t_eval, events; events and controller in the result; ensemble events and t_stop"


#: The most characters of the struct's name that the module's name keeps
#: (``_spark_<name>_<key>``): cargo's file names for it
#: (``lib<module>-<16 hex digits>.so``, ``.d``) then stay far below the
#: 255 bytes a file name may have.
MAX_SLUG = 64


#: The environment variable that builds every module without optimization
#: when it is ``0``, as ``optimize=False`` does (``1`` or unset: ``optimize``
#: decides). Being in the environment, it reaches the interpreters a
#: program starts (Ray workers, a test's subprocess), which then compute the
#: same cache key and load the same module.
OPTIMIZE_VARIABLE = "SPARK_COMPILE_OPTIMIZE"


def _optimized(optimize: bool) -> bool:
    """Whether a module is built with optimization: ``optimize``, unless
    ``SPARK_COMPILE_OPTIMIZE`` is ``0``. The one place that decides it: the
    cache key (:func:`cache_key`) and the cargo command (:func:`_build`)
    both follow it. :class:`ArgumentError` naming the variable for a value
    other than ``0`` or ``1``."""
    value = os.environ.get(OPTIMIZE_VARIABLE)
    if value is None or value == "1":
        return optimize
    if value == "0":
        return False
    raise ArgumentError(
        f"the environment variable {OPTIMIZE_VARIABLE} = {value!r} is neither 0 nor 1; set it to 0 to build "
        "every spark.compile module without optimization (as optimize=False does), or unset it"
    )


def cache_key(text: str, optimize: bool = True) -> str:
    """Hash of the text, the spark version, the source tree it builds
    against, the module interface (:data:`MODULE_INTERFACE`) and, for a
    module built without optimization (``optimize=False`` or
    ``SPARK_COMPILE_OPTIMIZE=0``, see :func:`_optimized`), that."""
    h = hashlib.sha256()
    parts = (text, _native.version(), _native.source_dir(), MODULE_INTERFACE) + (
        () if _optimized(optimize) else ("opt-level 0",)
    )
    for part in parts:
        h.update(part.encode())
        h.update(b"\0")
    return h.hexdigest()[:20]


def _environment_signature() -> str:
    """``PYO3_ENVIRONMENT_SIGNATURE`` as maturin sets it for this interpreter."""
    bits = 64 if sys.maxsize > 2**32 else 32
    return f"{sys.implementation.name}-{sys.version_info.major}.{sys.version_info.minor}-{bits}bit"


def _cargo() -> str:
    cargo = os.environ.get("CARGO") or shutil.which("cargo")
    if not cargo or not (os.path.isfile(cargo) and os.access(cargo, os.X_OK)):
        raise ToolchainError(TOOLCHAIN_HELP + (f" (CARGO = {cargo!r} is not an executable)" if cargo else ""))
    return cargo


def _package(module: str) -> str:
    """The cargo package name of the crate that builds ``module``."""
    return module.replace("_", "-").strip("-")


def _unoptimized_packages(module: str) -> tuple[str, ...]:
    """The packages a build without optimization compiles at opt-level 0:
    the declaration's crate, where its system's code is generated and
    monomorphized, and the spark crates it depends on by path. Cargo
    compiles a path dependency for each workspace apart (its artifacts'
    hash holds its path relative to the workspace root, or the whole path
    outside it), so a declaration's crate never reuses the wheel's build of
    spark-runtime and spark-python-core, and builds them in seconds at
    opt-level 0 instead of minutes optimized. The crates from crates.io
    (pyo3, numpy, nalgebra, rayon, serde, …) keep the release profile the
    environment gives them: they are the ones the wheel's build, or an
    optimized compile, already compiled in the target directory."""
    return (_package(module), "spark-runtime", "spark-python-core")


#: Features the wheel's build turns on in crates a declaration's crate
#: depends on, without that crate asking for them: the wheel's package
#: depends on `problems` (the registry), whose dependencies add them (its
#: own pins in python/Cargo.toml, clap's derive asking syn for `full`,
#: nalgebra's default features). Each is (kind, crate, version prefix,
#: features); :func:`_pins` asks for them, so that the crates from crates.io
#: resolve with the wheel's features and a target directory shared with
#: its build keeps them compiled (cargo compiles a crate again for each
#: other feature set, and every crate above it too).
FEATURE_PINS = (
    ("dependencies", "serde", "1", ("alloc",)),
    ("dependencies", "either", "1", ("use_std",)),
    ("dependencies", "bytemuck", "1", ("extern_crate_alloc",)),
    ("dependencies", "nalgebra", "0.33", ()),
    ("dependencies", "approx", "0.5", ()),
    ("dependencies", "simba", "0.9", ()),
    ("build-dependencies", "syn", "3", ("full",)),
)


def _pins(lock: Path) -> dict[str, list[str]]:
    """The manifest lines of :data:`FEATURE_PINS` for the crate versions
    ``lock`` (the source tree's Cargo.lock) holds, by table: each pins its
    crate to the locked version, so that no pin makes cargo resolve
    anything anew. A pin whose crate the lock does not hold at that
    version prefix is left out (the build then compiles that crate for its
    own features)."""
    try:
        locked = tomllib.loads(lock.read_text()).get("package", [])
    except (OSError, tomllib.TOMLDecodeError):
        return {}
    tables: dict[str, list[str]] = {}
    for table, crate, prefix, features in FEATURE_PINS:
        versions = [
            p["version"]
            for p in locked
            if p.get("name") == crate and (p.get("version") == prefix or p.get("version", "").startswith(prefix + "."))
        ]
        if len(versions) == 1:
            listed = ", ".join(f'"{f}"' for f in features)
            tables.setdefault(table, []).append(f'{crate} = {{ version = "={versions[0]}", features = [{listed}] }}')
    return tables


def _crate(source: Path, module: str, type_name: str, n: int, m: int, text: str) -> tuple[str, str]:
    runtime = (source / "spark-runtime").as_posix()
    core = (source / "python" / "core").as_posix()
    pins = _pins(source / "Cargo.lock")
    dependencies = "".join(line + "\n" for line in pins.get("dependencies", []))
    build_dependencies = "".join(line + "\n" for line in pins.get("build-dependencies", []))
    if build_dependencies:
        build_dependencies = "\n[build-dependencies]\n" + build_dependencies
    manifest = f"""[package]
name = "{_package(module)}"
version = "0.1.0"
edition = "2021"
publish = false

[lib]
name = "{module}"
path = "lib.rs"
crate-type = ["cdylib"]

[dependencies]
spark-runtime = {{ path = "{runtime}" }}
spark-python-core = {{ path = "{core}" }}
pyo3 = {{ version = "0.27", features = ["abi3-py311", "extension-module"] }}
{dependencies}{build_dependencies}
[workspace]

[profile.release]
debug = false
"""
    lib = (
        "// Generated by spark.compile from the declaration below.\n"
        "spark_runtime::nonholonomic_system! {\n"
        f"{text}\n"
        "}\n\n"
        f"spark_python_core::export_system!({module}, {type_name}, {n}, {m});\n"
    )
    return manifest, lib


class _Unverified(Exception):
    """A cached module file that does not match the digest recorded when it
    was installed (or has none)."""


def _digest(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            h.update(chunk)
    return h.hexdigest()


def _seal(library: Path) -> Path:
    """The file beside ``library`` holding its SHA-256, written when it is
    installed."""
    return library.with_name(library.name + ".sha256")


def _verify(library: Path) -> None:
    """Raises :class:`_Unverified` unless ``library`` has the digest
    recorded beside it: a truncated module file would be mapped by the
    dynamic loader past its end and end the process (SIGBUS), so a file is
    checked before it is loaded."""
    try:
        recorded = _seal(library).read_text().strip()
    except OSError as e:
        raise _Unverified(f"{library} has no recorded digest ({e})") from e
    if _digest(library) != recorded:
        raise _Unverified(f"{library} does not match the digest recorded when it was built (truncated or overwritten)")


def _load(module: str, path: Path) -> object:
    _verify(path)
    loader = importlib.machinery.ExtensionFileLoader(module, str(path))
    spec = importlib.util.spec_from_file_location(module, str(path), loader=loader)
    if spec is None:
        raise SparkError(f"could not load the compiled module {path}")
    mod = importlib.util.module_from_spec(spec)
    loader.exec_module(mod)
    sys.modules[module] = mod
    return mod


def _cache_dir(cache_dir) -> str | None:
    """``cache_dir`` as a str path (``None``: the default folder);
    :class:`TypeError` for what is no path, :class:`ArgumentError` for an
    empty path (which would name no folder; refused rather than read as the
    default), one holding a NUL character or one the file system's encoding
    cannot encode (a lone surrogate such as ``"\\ud800"``): the OS takes
    neither, and ``mkdir`` would raise its own ``ValueError`` naming no
    argument."""
    if cache_dir is None:
        return None
    try:
        path = os.fspath(cache_dir)
    except TypeError:
        raise TypeError(
            f"cache_dir = {_short(cache_dir)} is not a path; give a folder (a str, bytes or os.PathLike), or None "
            "for the default"
        ) from None
    if not path:
        raise ArgumentError(
            f"cache_dir = {path!r} names no folder; give the folder to cache compiled modules in, or None for the "
            "default (SPARK_CACHE_DIR or ~/.cache/spark-python)"
        )
    path = os.fsdecode(path)
    if "\0" in path:
        raise ArgumentError(f"cache_dir = {path!r} holds a NUL character, which no path can hold")
    try:
        os.fsencode(path)
    except UnicodeEncodeError as e:
        raise ArgumentError(
            f"cache_dir = {path!r} holds the lone surrogate U+{ord(path[e.start]):04X}, which the file system's "
            "encoding cannot encode, so no path can hold it; give a path of valid characters"
        ) from None
    return path


def _environment_cache_dir() -> str | None:
    """``SPARK_CACHE_DIR`` (``None`` when it is not set); :class:`ArgumentError`
    naming it when it is set but empty. An empty path names no folder, as
    ``cache_dir=""`` does, which is refused the same way: falling back to
    ``~/.cache/spark-python`` would put the cache (gigabytes of cargo's build
    folder) where the caller did not ask, typically when the variable was
    set from a shell variable that expanded to nothing."""
    value = os.environ.get("SPARK_CACHE_DIR")
    if value == "":
        raise ArgumentError(
            "the environment variable SPARK_CACHE_DIR is set but empty, which names no folder; set it to the folder "
            "to cache compiled modules in, or unset it for the default (~/.cache/spark-python), or give cache_dir="
        )
    return value


def _environment_target_dir() -> str | None:
    """``SPARK_CARGO_TARGET_DIR`` (``None`` when it is not set);
    :class:`ArgumentError` naming it when it is set but empty, as an empty
    ``SPARK_CACHE_DIR`` is: the empty path names no folder, and taking it
    as unset would build in ``<cache>/target``, gigabytes where the caller
    did not ask, rather than in the target directory meant to be shared."""
    value = os.environ.get("SPARK_CARGO_TARGET_DIR")
    if value == "":
        raise ArgumentError(
            "the environment variable SPARK_CARGO_TARGET_DIR is set but empty, which names no folder; set it to the "
            "cargo target directory to build compiled modules in, or unset it for the default (<cache>/target)"
        )
    return value


def compile_system(
    text: str, *, cache_dir: str | None = None, verbose: bool = False, optimize: bool = True
) -> System:
    if not isinstance(optimize, bool):
        raise TypeError(f"optimize must be a bool (True or False), got {type(optimize).__name__}")
    verbose = _flag("verbose", verbose)
    cache_dir = _cache_dir(cache_dir)
    if cache_dir is None:
        _environment_cache_dir()
    _environment_target_dir()
    optimize = _optimized(optimize)
    if not isinstance(text, str):
        raise TypeError(f"text = {_short(text)} is not a string; give the body of nonholonomic_system! as a str")
    _check_encodable(text)
    checked = _native.check_dsl(text)
    if "error" in checked:
        raise DslError(checked["error"], checked["line"], checked["column"])
    key = cache_key(text, optimize)
    # One thread at a time builds and loads: the threads of a process share
    # one build and one loaded module of each declaration.
    with _loading:
        if key not in _loaded:
            _loaded[key] = _build_and_load(text, checked, key, cache_dir, verbose, optimize)
        return _loaded[key]


def _check_encodable(text: str) -> None:
    """:class:`DslError` at the first character of ``text`` that UTF-8
    cannot encode (a lone surrogate such as ``"\\ud800"``, left by decoding
    bytes with ``errors="surrogateescape"`` or by a broken escape): the
    parser and cargo read UTF-8 text."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError as e:
        line = text.count("\n", 0, e.start) + 1
        column = e.start - (text.rfind("\n", 0, e.start) + 1) + 1
        raise DslError(
            f"the text is not valid Unicode: it holds the lone surrogate U+{ord(text[e.start]):04X}, which cannot be "
            "encoded as UTF-8; remove it (a text read from a file: decode the file as UTF-8 without "
            "errors=\"surrogateescape\")",
            line,
            column,
        ) from None


@dataclass(frozen=True)
class _Module:
    """One declaration's native module in the cache: what builds it (the
    declaration ``text`` of struct ``name`` with ``n`` coordinates and ``m``
    constraints, ``verbose`` and ``optimize``, as :func:`_optimized`
    decided it) and where it lives (the
    module name ``module``, the cache ``root``, the declaration's
    ``folder`` and its ``library`` file)."""

    text: str
    name: str
    n: int
    m: int
    module: str
    root: Path
    folder: Path
    library: Path
    verbose: bool
    optimize: bool


def _build_and_load(
    text: str, checked: dict, key: str, cache_dir: str | None, verbose: bool, optimize: bool
) -> System:
    """The system of the checked declaration ``text``: its module built
    into the cache unless it is there, then loaded."""
    name, n, m = checked["name"], checked["n"], checked["m"]
    # The module and crate names are ASCII whatever the struct's name (a
    # raw `r#Name`, letters beyond ASCII): cargo and the module's init
    # symbol take nothing else. They are cut to MAX_SLUG characters: file
    # names hold them with the key and cargo's suffixes, and a file name
    # has at most 255 bytes (the key alone tells declarations apart).
    slug = re.sub(r"[^0-9a-z_]", "_", name.removeprefix("r#").lower())[:MAX_SLUG]
    module = f"_spark_{slug}_{key}"
    root = cache_root(cache_dir)
    folder = root / key
    cached = _Module(text, name, n, m, module, root, folder, folder / f"{module}.abi3.so", verbose, optimize)
    if not cached.library.exists():
        with _folder_lock(folder):
            # Another process may have built it while we waited.
            if not cached.library.exists():
                _build(cached)
    mod = _load_or_rebuild(cached)
    info = mod.info()
    info["name"] = name
    info["cache_dir"] = str(root)
    info["optimized"] = optimize
    system = System(info, mod.integrate, mod.ensemble)
    system.source = text
    return system


def _identity(path: Path) -> tuple | None:
    """What tells one file at ``path`` from another put there later (an
    atomic rename gives a new inode), or None without a file."""
    try:
        st = path.stat()
    except OSError:
        return None
    return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)


def _load_or_rebuild(cached: _Module) -> object:
    """The module ``library``, loaded; a cached file that does not load
    (truncated, overwritten) is discarded and built again, once. Under the
    folder's lock, only a file that is still the one that failed is
    discarded: another process that met it too, or that replaced it
    meanwhile, loads the new one instead of building it again."""
    module, folder, library = cached.module, cached.folder, cached.library
    seen = _identity(library)
    try:
        return _load(module, library)
    except (_Unverified, ImportError, OSError) as first:
        with _folder_lock(folder):
            if _identity(library) == seen:
                try:
                    if library.is_dir() and not library.is_symlink():
                        shutil.rmtree(library)
                    else:
                        library.unlink(missing_ok=True)
                    _seal(library).unlink(missing_ok=True)
                except OSError as e:
                    raise SparkError(
                        f"the cached module {library} cannot be loaded ({first}) and spark.compile cannot delete it "
                        f"({e}); delete the folder {folder} and call spark.compile again"
                    ) from e
            if not library.exists():
                _build(cached)
        try:
            return _load(module, library)
        except (_Unverified, ImportError, OSError) as e:
            raise SparkError(
                f"the compiled module {library} cannot be loaded even after spark.compile built it again ({e}); "
                f"delete the folder {folder} and call spark.compile again (or give cache_dir= or SPARK_CACHE_DIR "
                "another folder)"
            ) from e


@contextlib.contextmanager
def _folder_lock(folder: Path):
    """Holds an exclusive lock on ``folder`` (``.lock``, an advisory
    ``flock``, released when the file closes, also when the process dies):
    compiles of one declaration in several processes (Ray workers on one
    machine with an empty cache) build and install its module one after the
    other, instead of rewriting its crate and its module file under each
    other."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        lock = open(folder / ".lock", "a")
    except OSError as e:
        raise SparkError(
            f"spark.compile cannot use the cache folder {folder}: {e}; give cache_dir= (or SPARK_CACHE_DIR) a "
            "folder it can create and write"
        ) from e
    with lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def _build(cached: _Module) -> None:
    """Builds the declaration's crate in ``folder`` with cargo (in its
    release profile; without ``optimize``, that crate and the spark crates
    at opt-level 0, see :func:`_unoptimized_packages`)
    and installs its module as ``library`` (copied under a temporary name,
    then renamed, so ``library`` is complete whenever it exists)."""
    name, module, folder, library = cached.name, cached.module, cached.folder, cached.library
    cargo = _cargo()
    source = Path(_native.source_dir())
    if not (source / "spark-runtime" / "Cargo.toml").exists():
        raise SparkError(
            f"spark.compile builds against the spark source tree this package was built from, {source}, "
            "which is not there any more; rebuild the package from a spark checkout"
        )
    manifest, lib = _crate(source, module, name, cached.n, cached.m, cached.text)
    try:
        (folder / "Cargo.toml").write_text(manifest)
        (folder / "lib.rs").write_text(lib)
        lock = source / "Cargo.lock"
        if lock.exists():
            shutil.copyfile(lock, folder / "Cargo.lock")
    except OSError as e:
        raise SparkError(
            f"spark.compile cannot write the declaration's crate into the cache folder {folder}: {e}; give "
            "cache_dir= (or SPARK_CACHE_DIR) a folder it can create and write"
        ) from e
    target = Path(_environment_target_dir() or (cached.root / "target"))
    env = dict(os.environ, CARGO_TARGET_DIR=str(target))
    # PyO3's build script is rerun whenever these differ from the last
    # build in the target directory: the interpreter that will load the
    # module, the signature maturin sets for it and maturin's mark of an
    # extension module. With the values a wheel build made with
    # `maturin build -i <this interpreter>` used, a target directory shared
    # with it keeps PyO3 and the crates above it compiled, instead of each
    # build invalidating the other's.
    env.setdefault("PYO3_PYTHON", sys.executable)
    env.setdefault("PYO3_ENVIRONMENT_SIGNATURE", _environment_signature())
    env.setdefault("PYO3_BUILD_EXTENSION_MODULE", "1")
    cmd = [cargo, "build", "--release", "--quiet", "--manifest-path", str(folder / "Cargo.toml")]
    if not cached.optimize:
        for package in _unoptimized_packages(cached.module):
            cmd += ["--config", f'profile.release.package."{package}".opt-level=0']
    try:
        done = subprocess.run(cmd, env=env, capture_output=not cached.verbose, text=True)
    except OSError as e:
        raise ToolchainError(f"{TOOLCHAIN_HELP} (running {cargo} failed: {e})") from e
    if done.returncode != 0:
        raise SparkError(
            f"cargo could not build the declaration of {name} (crate in {folder}):\n{done.stderr or ''}"
        )
    built = target / "release" / f"lib{module}.so"
    if not built.exists():
        raise SparkError(f"cargo reported success but {built} is missing")
    staging = folder / f".{module}.so.tmp"
    seal = folder / f".{module}.sha256.tmp"
    try:
        shutil.copyfile(built, staging)
        seal.write_text(_digest(staging) + "\n")
        # The digest first: whenever `library` exists, the digest beside it is its own.
        os.replace(seal, _seal(library))
        os.replace(staging, library)
    except OSError as e:
        for leftover in (staging, seal):
            with contextlib.suppress(OSError):
                leftover.unlink(missing_ok=True)
        raise SparkError(
            f"spark.compile cannot install the built module {built} as {library}: {e}; give cache_dir= (or "
            "SPARK_CACHE_DIR) a folder it can create and write"
        ) from e
