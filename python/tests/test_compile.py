"""`spark.compile`: DSL text from Python, checked by the macro's parser, built
by cargo into a cached native module."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import spark
import spark._compile
from conftest import REPO, interrupt_after_start
from spark._compile import cache_key

pytestmark = pytest.mark.usefixtures("compiles_without_optimization")


def declaration(type_name: str) -> str:
    """The body of the `nonholonomic_system!` block declaring `type_name` in
    problems/src/systems/paper.rs: the text the Rust registry was compiled from."""
    source = (REPO / "problems" / "src" / "systems" / "paper.rs").read_text()
    for block in source.split("nonholonomic_system! {\n")[1:]:
        body = block.split("\n}\n")[0]
        if f"pub struct {type_name} {{" in body:
            return body
    raise AssertionError(f"{type_name} not found")


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("spark-cache")


def test_compiled_system_matches_the_same_declaration_compiled_in_rust(cache):
    skate = spark.compile(declaration("Skate"), cache_dir=str(cache))
    registered = spark.system("skate")
    assert (skate.name, skate.n, skate.m, skate.coordinates) == ("Skate", 3, 1, registered.coordinates)
    assert skate.parameters == registered.parameters
    assert skate.structure == registered.structure
    for method, s in (("gauss", 2), ("lobatto-iiia-b", 3), ("lobatto-iiia-b-d", 4)):
        kw = dict(q0=[0.0, 0.0, 0.0], v0=[0.0, 0.0, 1.0], params={"g": 9.81}, multipliers=True)
        a = skate.integrate(method, s, 0.1, 300, **kw)
        b = registered.integrate(method, s, 0.1, 300, **kw)
        for field in ("t", "q", "v", "energy", "constraint", "psi"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=f"{method} {field}")
    q0s, v0s = np.zeros((3, 3)), np.array([[0, 0, 1.0], [0, 0, 2.0], [0, 0, 0.5]])
    np.testing.assert_array_equal(
        skate.ensemble("gauss", 2, 0.1, 50, q0s, v0s).q, registered.ensemble("gauss", 2, 0.1, 50, q0s, v0s).q
    )
    with pytest.raises(spark.SparkError, match="v0 violates the constraints.*pass project_v0=True"):
        skate.integrate("gauss", 2, 0.1, 5, q0=[0, 0, 0], v0=[0, 1.0, 0])
    # An ensemble takes no project_v0, and its message does not offer it,
    # in the lanes and in a member's run alone (output times).
    for kw in (dict(), dict(t_eval=[0.2])):
        with pytest.raises(spark.SparkError, match="member 2: v0 violates the constraints") as e:
            skate.ensemble("gauss", 2, 0.1, 5, q0s, np.array([[0, 0, 1.0], [0, 0, 2.0], [0, 1.0, 0]]), **kw)
        assert "give the member a row of v0s with k = 0" in str(e.value)
        assert "pass project_v0" not in str(e.value)


def test_an_unoptimized_module_builds_at_opt_level_0_and_is_cached_apart(cache, monkeypatch, tmp_path):
    text = declaration("Skate")
    # This module's fixture sets SPARK_COMPILE_OPTIMIZE=0: the first test's
    # module is the one optimize=False builds, under the same key.
    knob = spark.compile(text, cache_dir=str(cache))
    assert knob.info["optimized"] is False and cache_key(text) == cache_key(text, optimize=False)
    assert spark.compile(text, cache_dir=str(cache), optimize=False) is knob
    monkeypatch.delenv("SPARK_COMPILE_OPTIMIZE")
    assert cache_key(text, optimize=False) != cache_key(text)
    # The cargo commands of a new declaration, recorded instead of run.
    commands = []

    class Recorded(Exception):
        pass

    def record(cmd, env, **kwargs):
        commands.append((cmd, env))
        raise Recorded

    monkeypatch.setattr(spark._compile.subprocess, "run", record)
    recorded = text + "\n// recorded"
    for optimize, knob_value in ((True, None), (False, None), (True, "0"), (False, "1")):
        if knob_value is not None:
            monkeypatch.setenv("SPARK_COMPILE_OPTIMIZE", knob_value)
        with pytest.raises(Recorded):
            spark.compile(recorded, cache_dir=str(tmp_path), optimize=optimize)
    (optimized, _), *unoptimized = commands
    assert "--config" not in optimized, optimized
    # Only the declaration's crate and the spark crates are built at
    # opt-level 0: the crates from crates.io keep the caller's release
    # profile, so a target directory shared with the wheel's build keeps
    # them compiled.
    package = f"spark-skate-{cache_key(recorded, optimize=False)}"
    overrides = [
        f'profile.release.package."{name}".opt-level=0' for name in (package, "spark-runtime", "spark-python-core")
    ]
    for cmd, env in unoptimized:
        assert [cmd[i + 1] for i, arg in enumerate(cmd) if arg == "--config"] == overrides, cmd
        assert env.get("CARGO_PROFILE_RELEASE_OPT_LEVEL") == os.environ.get("CARGO_PROFILE_RELEASE_OPT_LEVEL")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        {cache_key(recorded), cache_key(recorded, optimize=False)}
    )
    monkeypatch.setenv("SPARK_COMPILE_OPTIMIZE", "2")
    for call in (lambda: cache_key(text), lambda: spark.compile(text, cache_dir=str(cache))):
        with pytest.raises(spark.ArgumentError, match=r"SPARK_COMPILE_OPTIMIZE = '2' is neither 0 nor 1"):
            call()
    with pytest.raises(TypeError, match="optimize must be a bool"):
        spark.compile(text, cache_dir=str(cache), optimize=1)


def test_cached_module_loads_without_cargo(cache):
    """A second process with no cargo on PATH loads the module built above."""
    script = textwrap.dedent(
        f"""
        import spark, sys
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        from test_compile import declaration
        s = spark.compile(declaration("Skate"), cache_dir={str(cache)!r})
        print(s.integrate("gauss", 2, 0.1, 10, q0=[0, 0, 0], v0=[0, 0, 1]).q[-1, 2])
        """
    )
    env = dict(os.environ, PATH="/nonexistent")
    env.pop("CARGO", None)
    done = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert float(done.stdout) > 0.9


def test_ctrl_c_stops_a_long_run_of_a_compiled_system(cache):
    """A run and an ensemble of the module built above, interrupted."""
    load = textwrap.dedent(
        f"""
        import numpy as np, spark, sys
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        from test_compile import declaration
        s = spark.compile(declaration("Skate"), cache_dir={str(cache)!r})
        print("running")
        """
    )
    long_run = 's.integrate("gauss", 2, 0.1, 2**40, q0=[0, 0, 0], v0=[0, 0, 1], every=2**30)\n'
    ensemble = 's.ensemble("gauss", 2, 0.1, 2**40, np.zeros((9, 3)), np.array([[0, 0, 1.0]] * 9), every=2**30)\n'
    for call in (long_run, ensemble):
        took, err = interrupt_after_start(load + call)
        assert "KeyboardInterrupt" in err, err
        assert took < 10.0, f"{took:.1f} s from Ctrl-C to exit"


BAD = """
pub struct Bad {
    coordinates: [x, y],
    lagrangian: dot(x)^2/2 + dot(y)^2/2 - abs(x),
}
"""


def test_bad_dsl_raises_with_line_and_column(tmp_path):
    with pytest.raises(spark.DslError) as info:
        spark.compile(BAD, cache_dir=str(tmp_path))
    e = info.value
    assert (e.line, e.column) == (4, 43), str(e)
    assert "abs" in e.message
    assert not any(tmp_path.iterdir()), "a bad declaration must not reach cargo"
    with pytest.raises(spark.DslError) as info:
        spark.compile("pub struct P {\n    coordinates: [x],\n    lagrangian: dot(x)^2 + ,\n}", cache_dir=str(tmp_path))
    assert info.value.line == 3
    with pytest.raises(spark.DslError) as info:
        spark.compile("pub struct P { coordinates: [x], lagrangian: dot(x)^2 \"", cache_dir=str(tmp_path))
    assert info.value.line == 1


def test_missing_toolchain_raises_a_clear_error(tmp_path, monkeypatch):
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    monkeypatch.delenv("CARGO", raising=False)
    text = declaration("NonholonomicParticle")
    with pytest.raises(spark.ToolchainError, match=r"needs the Rust toolchain \(cargo\).*rustup"):
        spark.compile(text, cache_dir=str(tmp_path / "cache"))
    monkeypatch.setenv("CARGO", str(tmp_path / "no-such-cargo"))
    with pytest.raises(spark.ToolchainError, match="is not an executable"):
        spark.compile(text, cache_dir=str(tmp_path / "cache"))


def many_coordinates(n: int) -> str:
    """A declaration with `n` coupled coordinates (the McLachlan-Perlmutter
    particles' shape): its derivatives take the engine time growing like n²."""
    q = [f"q{i}" for i in range(1, n + 1)]
    kinetic = " + ".join(f"dot({x})^2" for x in q)
    potential = " + ".join(f"{a}^2*{b}^2" for a, b in zip(q, q[1:]))
    constraint = " + ".join(f"{x}*dot({x})" for x in q[n // 2 :])
    return (
        f"pub struct Big {{\n    coordinates: [{', '.join(q)}],\n    lagrangian: ({kinetic})/2 - ({potential})/2,\n"
        f"    constraints: [ dot(q1) + {constraint} ],\n}}\n"
    )


def test_a_cache_folder_that_cannot_be_made_is_a_spark_error(tmp_path):
    # A file as cache_dir is a SparkError naming it, not the OS's
    # NotADirectoryError from mkdir.
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    text = declaration("Skate") + "\n// cache in a file"
    with pytest.raises(spark.SparkError, match=r"cannot use the cache folder .*a-file.*give cache_dir="):
        spark.compile(text, cache_dir=str(blocker))


def test_more_coordinates_than_supported_are_refused_at_once(tmp_path):
    # 3000 coordinates would stall the check for over 300 s (the engine's
    # work grows like n²); they are refused at the coordinate list, before cargo.
    import time

    start = time.monotonic()
    with pytest.raises(spark.DslError, match=r"3000 coordinates: spark supports at most 400") as info:
        spark.compile(many_coordinates(3000), cache_dir=str(tmp_path))
    assert time.monotonic() - start < 5.0
    assert (info.value.line, info.value.column) == (2, 18), str(info.value)
    assert not any(tmp_path.iterdir()), "a refused declaration must not reach cargo"


def _dsl_error_in_child(build_text: str, timeout: float) -> str:
    """Runs `spark.compile(text)` in a child interpreter, with `text` made by
    the statements `build_text`, and returns what it prints: the line,
    column and message of the `DslError`. A crash (a stack overflow, an
    exhausted memory) fails the calling test rather than pytest."""
    code = (
        "import spark\n"
        + textwrap.dedent(build_text)
        + textwrap.dedent(
            """
            try:
                spark.compile(text)
            except spark.DslError as e:
                print(e.line, e.column, e.message)
            """
        )
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, (done.returncode, done.stderr[-2000:])
    return done.stdout


def test_an_expression_of_too_many_operations_is_a_dsl_error_not_a_crash():
    """A sum of 200 000 terms is a tree 200 000 levels deep, whose passes
    would overflow the stack of the check thread and kill the interpreter
    (SIGSEGV); it is refused at the first operation beyond the limit."""
    out = _dsl_error_in_child(
        """
        text = "pub struct Long { coordinates: [x], lagrangian: dot(x)^2" + " + x" * 200_000 + " }"
        """,
        timeout=120,
    )
    assert "the lagrangian has more than 20000 operations" in out, out


def test_a_declaration_whose_derivatives_swell_is_a_dsl_error_in_seconds():
    """The second derivative of a product of k factors in one coordinate has
    about k³ operands: 150 factors `(x + i)` (1 KB of text) take minutes and
    gigabytes to differentiate and emit, 400 all the memory, which ends the
    interpreter. Past the graph's limit the check refuses the declaration
    at its struct's name."""
    out = _dsl_error_in_child(
        """
        factors = "*".join(f"(x + {i})" for i in range(1, 151))
        text = "pub struct Swell { coordinates: [x], lagrangian: dot(x)^2 + " + factors + " }"
        """,
        timeout=300,
    )
    assert "the derivatives of `Swell` grow beyond the engine's limit" in out, out
    assert "MAX_GRAPH_SIZE" in out, out


def test_ctrl_c_interrupts_the_check_of_a_large_declaration():
    # The check of 400 coupled coordinates takes seconds; Ctrl-C ends it at
    # once (the check releases the GIL, so the caller's signal handlers run).
    script = (
        "import sys, spark\n"
        f"sys.path.insert(0, {str(Path(__file__).parent)!r})\n"
        "from test_compile import many_coordinates\n"
        "text = many_coordinates(400)\n"
        "print('running')\n"
        "spark._native.check_dsl(text)\n"
        "print('checked', file=sys.stderr)\n"
    )
    took, err = interrupt_after_start(script, delay=0.3)
    assert "KeyboardInterrupt" in err and "checked" not in err, err
    assert took < 1.5, f"{took:.1f} s from Ctrl-C to exit"


CONCURRENT = textwrap.dedent(
    """
    import shutil, sys, threading, time
    import spark, spark._compile
    sys.path.insert(0, {tests!r})
    from test_compile import declaration

    def slow_copy(src, dst, *args, **kwargs):
        # A copy as slow as on a network file system (a cache shared by the
        # nodes of a cluster): the others get there before it ends.
        with open(src, "rb") as f:
            data = f.read()
        with open(dst, "wb") as f:
            f.write(data[: len(data) // 2])
            f.flush()
            time.sleep(1.0)
            f.write(data[len(data) // 2 :])
        return dst

    spark._compile.shutil.copyfile = slow_copy
    text = declaration("Skate") + "\\n// compiled concurrently"
    results = []

    def one():
        s = spark.compile(text, cache_dir={cache!r})
        results.append(s.integrate("gauss", 2, 0.1, 10, q0=[0, 0, 0], v0=[0, 0, 1]).q[-1, 2])

    threads = [threading.Thread(target=one) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(results) == 2 and results[0] == results[1] > 0.9, results
    print("ok")
    """
)


def test_concurrent_compiles_of_one_declaration_each_get_a_working_module(tmp_path):
    """Two processes of two threads each compile one declaration into one
    empty cache (Ray workers sharing a cache): each gets a working module.
    They rewrote its crate under each other and installed the module
    through one temporary file, which one of them renamed away from the
    others while they still wrote into it (FileNotFoundError, and a module
    file assembled from several copies)."""
    script = CONCURRENT.format(tests=str(Path(__file__).parent), cache=str(tmp_path / "cache"))
    children = [
        subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for _ in range(2)
    ]
    for child in children:
        out, err = child.communicate(timeout=600)
        assert child.returncode == 0 and out.strip() == "ok", err
    leftovers = [p.name for p in (tmp_path / "cache").rglob("*.tmp")]
    assert not leftovers, leftovers


def test_a_raw_or_non_ascii_struct_name_compiles(tmp_path):
    # The module and crate names are ASCII, not the struct's name: `r#Foo`
    # would make a package name cargo refuses (`#`), `Ñame` a module whose
    # init symbol fails to link, both after the check accepts the declaration.
    text = "pub struct r#Ñame {\n    coordinates: [x],\n    lagrangian: dot(x)^2/2 - x^2/2,\n}\n"
    s = spark.compile(text, cache_dir=str(tmp_path))
    assert s.name == "r#Ñame"
    run = s.integrate("gauss", 2, 0.1, 10, q0=[1.0], v0=[0.0])
    assert abs(run.q[-1, 0] - np.cos(1.0)) < 1e-4


def test_a_struct_name_longer_than_a_file_name_compiles(tmp_path):
    # The module's file names hold the struct's name: one of 300 letters
    # made them longer than the 255 bytes a file name may have, and the
    # declaration the check accepted failed with a bare OSError.
    name = "Long" + "g" * 296
    text = f"pub struct {name} {{\n    coordinates: [x],\n    lagrangian: dot(x)^2/2 - x^2/2,\n}}\n"
    s = spark.compile(text, cache_dir=str(tmp_path))
    assert s.name == name
    run = s.integrate("gauss", 2, 0.1, 10, q0=[1.0], v0=[0.0])
    assert abs(run.q[-1, 0] - np.cos(1.0)) < 1e-4


def test_struct_names_and_attributes_that_cannot_build_are_dsl_errors_before_cargo(tmp_path):
    # Each passed a check that did not know the module's code and then failed
    # in cargo with rustc's output: a primitive type the generated code names,
    # a runtime path the module does not have, a condition that compiles the
    # struct out, a derive that f64 fields do not support, another crate's
    # attribute.
    body = "{ coordinates: [x], parameters: { k = 1.0 }, lagrangian: dot(x)^2/2 - k*x^2/2 }"
    cases = [
        ("pub struct f64 " + body, (1, 12), "`f64` names a Rust primitive type"),
        ("pub struct usize " + body, (1, 12), "choose another struct name"),
        ("#[spark(crate = ::nope)]\npub struct S " + body, (1, 17), "remove `#[spark(crate = …)]`"),
        ("/// Doc.\n#[cfg(any())]\npub struct S " + body, (2, 1), "`#[cfg(…)]`"),
        ("#[derive(Debug, Hash)]\npub struct S " + body, (1, 17), "cannot derive `Hash`"),
        ("#[serde(rename_all = \"camelCase\")]\npub struct S " + body, (1, 1), "does not take `#[serde…]`"),
    ]
    for text, at, needle in cases:
        with pytest.raises(spark.DslError) as info:
            spark.compile(text, cache_dir=str(tmp_path))
        assert (info.value.line, info.value.column) == at and needle in info.value.message, (text, str(info.value))
    assert not any(tmp_path.iterdir()), "a bad declaration must not reach cargo"


def test_struct_names_like_the_module_functions_and_harmless_attributes_compile(tmp_path):
    # `info`, `integrate` and `ensemble` name the module's functions in
    # Python; the Rust items export_system! defines do not clash with them.
    # Doc comments, std derives and lint attributes build as in Rust.
    attributes = (
        "/// A spring.\n#[derive(Debug, Clone, PartialOrd)]\n#[allow(dead_code)]\n#[must_use]\n"
        "#[spark(crate = ::spark_runtime)]\n"
    )
    for name in ["info", "integrate", "ensemble"]:
        text = f"{attributes}pub struct {name} {{\n    coordinates: [x],\n    lagrangian: dot(x)^2/2 - x^2/2,\n}}\n"
        s = spark.compile(text, cache_dir=str(tmp_path))
        assert s.name == name
        run = s.integrate("gauss", 2, 0.1, 10, q0=[1.0], v0=[0.0])
        assert abs(run.q[-1, 0] - np.cos(1.0)) < 1e-4


def test_a_lone_surrogate_is_a_dsl_error_at_its_position(tmp_path):
    # The UTF-8 parser cannot take a lone surrogate (text decoded with
    # errors="surrogateescape"): the bare UnicodeEncodeError of the
    # conversion to Rust becomes a DslError at the character.
    text = "pub struct S {\n    coordinates: [x],\n    lagrangian: dot(x)^2/2 - x^2/2, // \ud800\n}\n"
    with pytest.raises(spark.DslError, match=r"not valid Unicode.*U\+D800.*cannot be encoded as UTF-8") as info:
        spark.compile(text, cache_dir=str(tmp_path))
    assert (info.value.line, info.value.column) == (3, 40), str(info.value)
    assert not any(tmp_path.iterdir()), "a bad declaration must not reach cargo"


def fake_cargo(monkeypatch, tmp_path: Path) -> list:
    """Replaces cargo by a stand-in that writes a module file of a few
    bytes where cargo puts the module, and returns the list of the builds
    it made: the tests of the cache's own files run without a toolchain."""
    builds = []
    cargo = tmp_path / "cargo"
    cargo.write_text("#!/bin/sh\n")
    cargo.chmod(0o755)
    monkeypatch.setenv("CARGO", str(cargo))

    def run(cmd, env, **kwargs):
        manifest = Path(cmd[cmd.index("--manifest-path") + 1])
        module = manifest.read_text().split('[lib]\nname = "')[1].split('"')[0]
        built = Path(env["CARGO_TARGET_DIR"]) / "release" / f"lib{module}.so"
        built.parent.mkdir(parents=True, exist_ok=True)
        built.write_bytes(b"not a shared library")
        builds.append(module)
        return subprocess.CompletedProcess(cmd, 0, "", "")

    monkeypatch.setattr(spark._compile.subprocess, "run", run)
    return builds


def test_a_module_that_cannot_be_installed_is_a_spark_error_without_leftovers(tmp_path, monkeypatch):
    # Copying or renaming the built module into the cache failed with a bare
    # OSError and left its temporary copy in the cache folder.
    fake_cargo(monkeypatch, tmp_path)
    cache = tmp_path / "cache"
    replace = os.replace

    def failing_replace(src, dst):
        if str(dst).endswith(".abi3.so"):
            raise OSError(30, "Read-only file system", str(dst))
        return replace(src, dst)

    monkeypatch.setattr(spark._compile.os, "replace", failing_replace)
    text = declaration("Skate") + "\n// install fails"
    with pytest.raises(
        spark.SparkError, match=r"cannot install the built module .*abi3\.so.*Read-only file system.*SPARK_CACHE_DIR"
    ):
        spark.compile(text, cache_dir=str(cache))
    assert not list(cache.rglob("*.tmp")), list(cache.rglob("*.tmp"))
    assert not list(cache.rglob("*.abi3.so"))

    copyfile = spark._compile.shutil.copyfile

    def failing_copy(src, dst, *args, **kwargs):
        if str(dst).endswith(".tmp"):
            Path(dst).write_bytes(b"half")
            raise OSError(28, "No space left on device", str(dst))
        return copyfile(src, dst)

    monkeypatch.setattr(spark._compile.shutil, "copyfile", failing_copy)
    monkeypatch.setattr(spark._compile.os, "replace", replace)
    with pytest.raises(spark.SparkError, match=r"cannot install .*No space left on device.*SPARK_CACHE_DIR"):
        spark.compile(text, cache_dir=str(cache))
    assert not list(cache.rglob("*.tmp")), list(cache.rglob("*.tmp"))


def test_a_corrupt_cached_module_is_rebuilt(cache):
    # A cached module file overwritten with garbage raised a bare ImportError
    # on every later compile, and a truncated one ended the interpreter that
    # loaded it (SIGBUS, the loader mapping it past its end); the cache
    # checks the file against its digest, discards it and builds it again.
    text = declaration("Skate") + "\n// corrupt cache"
    key = cache_key(text)
    library = cache / key / f"_spark_skate_{key}.abi3.so"
    library.parent.mkdir(parents=True, exist_ok=True)
    library.write_bytes(b"\x7fELF garbage")
    s = spark.compile(text, cache_dir=str(cache))
    assert library.stat().st_size > 10_000
    assert abs(s.integrate("gauss", 2, 0.1, 10, q0=[0, 0, 0], v0=[0, 0, 1]).q[-1, 2] - 1.0) < 0.2
    # A module truncated after it was built, met by a fresh interpreter
    # (written beside and renamed over it: this process has the module
    # mapped, and a file rewritten in place under a mapping is a SIGBUS).
    data = library.read_bytes()
    truncated = library.with_name("truncated")
    truncated.write_bytes(data[: len(data) // 3])
    os.replace(truncated, library)
    script = textwrap.dedent(
        f"""
        import spark, sys
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        from test_compile import declaration
        s = spark.compile(declaration("Skate") + "\\n// corrupt cache", cache_dir={str(cache)!r})
        print(s.integrate("gauss", 2, 0.1, 10, q0=[0, 0, 0], v0=[0, 0, 1]).q[-1, 2])
        """
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert float(done.stdout) > 0.9
    assert library.stat().st_size > len(data) // 3 and library.read_bytes() != data[: len(data) // 3]


def test_a_cached_module_that_stays_unloadable_is_a_spark_error_naming_it(tmp_path, monkeypatch):
    builds = fake_cargo(monkeypatch, tmp_path)
    cache = tmp_path / "cache"
    text = declaration("Skate") + "\n// unloadable"
    key = cache_key(text)
    library = cache / key / f"_spark_skate_{key}.abi3.so"
    library.parent.mkdir(parents=True)
    library.write_bytes(b"garbage")
    with pytest.raises(spark.SparkError, match=r"cannot be loaded even after spark\.compile built it again") as info:
        spark.compile(text, cache_dir=str(cache))
    assert str(library) in str(info.value) and f"delete the folder {library.parent}" in str(info.value)
    assert len(builds) == 1, builds


def test_a_name_of_millions_of_characters_is_quoted_as_an_excerpt(tmp_path):
    # The DslError quoted an unknown name of 10⁷ characters whole (10 MB of
    # message); it shows its first 40 characters and its length.
    name = "b" + "a" * (10**7 - 1)
    text = "pub struct S {\n    coordinates: [x],\n    lagrangian: dot(x)^2/2 - " + name + ",\n}\n"
    with pytest.raises(spark.DslError) as info:
        spark.compile(text, cache_dir=str(tmp_path))
    message = info.value.message
    assert len(message) < 400, message[:400]
    assert "`b" + "a" * 39 + "… (10000000 characters)`" in message, message
    assert (info.value.line, info.value.column) == (3, 30), str(info.value)[:200]
    # An ordinary name is quoted whole.
    with pytest.raises(spark.DslError, match="unknown identifier `zeta`"):
        spark.compile(text.replace(name, "zeta"), cache_dir=str(tmp_path))


def test_a_cache_dir_that_names_no_folder_is_an_argument_error_before_the_check(tmp_path, monkeypatch):
    # Unchecked, a NUL in cache_dir raised the OS layer's raw ValueError
    # ("embedded null byte") from mkdir, after the declaration's check; an
    # empty one silently used the default cache. Each is refused first,
    # naming cache_dir, and nothing is written anywhere.
    monkeypatch.setenv("SPARK_CACHE_DIR", str(tmp_path / "default"))
    text = declaration("Skate") + "\n// cache_dir refused"
    cases = {
        "": r"cache_dir = '' names no folder",
        b"": r"cache_dir = b'' names no folder",
        str(tmp_path / "a\0b"): r"cache_dir = .* holds a NUL character",
        str(tmp_path / "a\ud800"): r"cache_dir = .* lone surrogate U\+D800",
    }
    for cache_dir, words in cases.items():
        with pytest.raises(spark.ArgumentError, match=words):
            spark.compile(text, cache_dir=cache_dir)
    with pytest.raises(TypeError, match=r"^cache_dir = 5 is not a path"):
        spark.compile(text, cache_dir=5)
    with pytest.raises(TypeError, match=r"^verbose = 'yes' is not a bool"):
        spark.compile(text, cache_dir=str(tmp_path), verbose="yes")
    with pytest.raises(TypeError, match=r"^text = 5 is not a string"):
        spark.compile(5, cache_dir=str(tmp_path))
    assert not list(tmp_path.iterdir())


def test_an_empty_spark_cache_dir_is_an_argument_error_naming_it(tmp_path, monkeypatch):
    # A SPARK_CACHE_DIR set to nothing (a shell variable that expanded to
    # nothing) names no folder, as cache_dir="" does: it is refused before
    # the check, naming the variable, instead of building into the default
    # cache under the home folder.
    monkeypatch.setenv("SPARK_CACHE_DIR", "")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    for text in (BAD, declaration("Skate") + "\n// empty SPARK_CACHE_DIR"):
        with pytest.raises(spark.ArgumentError, match=r"^the environment variable SPARK_CACHE_DIR is set but empty"):
            spark.compile(text)
    with pytest.raises(spark.ArgumentError, match=r"SPARK_CACHE_DIR is set but empty"):
        spark._compile.cache_root()
    assert not list(tmp_path.iterdir())
    # A cache_dir given takes precedence: the variable is not read.
    with pytest.raises(spark.DslError):
        spark.compile(BAD, cache_dir=str(tmp_path / "given"))
    assert spark._compile.cache_root(str(tmp_path / "given")) == tmp_path / "given"


def test_a_compiled_system_refuses_bad_steps_and_initial_states_as_argument_errors(cache):
    # A compiled system has no default h, run length or initial state: a
    # missing one is the caller's bad argument, as are a step size that is
    # zero or not finite and initial states of another width or not
    # finite, refused before the run by the package and by the module's own
    # functions (whose run failed with a SparkError, or member 0's).
    skate = spark.compile(declaration("Skate"), cache_dir=str(cache))
    state = dict(q0=[0, 0, 0], v0=[0, 0, 1])
    q0s, v0s = [[0, 0, 0], [0, 0, 0]], [[0, 0, 1], [0, 0, 2]]
    for words, call in (
        (r"^give the step size h=", lambda: skate.integrate("gauss", 2, None, 3, **state)),
        (r"^give steps= .* or t_end=", lambda: skate.integrate("gauss", 2, 0.1, **state)),
        (r"^give q0=, the initial q of Skate \(3 numbers\)", lambda: skate.integrate("gauss", 2, 0.1, 3)),
        (r"^step size h = 0.0 must be finite", lambda: skate.integrate("gauss", 2, 0.0, 3, **state)),
        (r"^t_end = -1\.0 lies behind t0", lambda: skate.integrate("gauss", 2, 0.1, t_end=-1.0, **state)),
        (r"^q0s and v0s must have shape \(members, 3\) for Skate", lambda: skate.ensemble(
            "gauss", 2, 0.1, 3, [[0, 0]], [[0, 1]])),
        (r"^v0s\[1, 2\] = nan is not finite \(member 1\)", lambda: skate.ensemble(
            "gauss", 2, 0.1, 3, q0s, [[0, 0, 1], [0, 0, float("nan")]])),
    ):
        with pytest.raises(spark.ArgumentError, match=words):
            call()
    request = {"method": "gauss", "s": 2, "h": 0.1, "steps": 3, **state}
    members = {**request, "q0s": q0s, "v0s": v0s}
    for words, call in (
        (r"^step size h = NaN must be finite and nonzero", lambda: skate._integrate({**request, "h": float("nan")})),
        (r"^the request has no `h`", lambda: skate._integrate({**request, "h": None})),
        (r"^`steps` = 2.5 must be a whole number", lambda: skate._ensemble({**members, "steps": 2.5})),
        (r"^`t_end` applies to a tolerance-driven request", lambda: skate._integrate({**request, "t_end": 1.0})),
        (r"^q0\[0\] = inf is not finite", lambda: skate._integrate({**request, "q0": [float("inf"), 0, 0]})),
        (r"^v0 has 2 entries but the system has 3 coordinates", lambda: skate._integrate({**request, "v0": [0, 1]})),
        (r"^q0s and v0s must have shape \(members, 3\) = \(1, 3\); got rows of 2",
         lambda: skate._ensemble({**members, "q0s": [[0, 0]], "v0s": [[0, 1]]})),
        (r"^row 1 of v0s has 2 numbers", lambda: skate._ensemble({**members, "v0s": [[0, 0, 1], [0, 1]]})),
        (r"^q0s\[1, 0\] = NaN is not finite \(member 1\)",
         lambda: skate._ensemble({**members, "q0s": [[0, 0, 0], [float("nan"), 0, 0]]})),
    ):
        with pytest.raises(spark.ArgumentError, match=words):
            call()


def test_an_empty_spark_cargo_target_dir_is_an_argument_error_naming_it(tmp_path, monkeypatch):
    # A SPARK_CARGO_TARGET_DIR set to nothing names no folder, as an empty
    # SPARK_CACHE_DIR does: refused before the check, naming the variable,
    # instead of being taken as unset and building in <cache>/target.
    monkeypatch.setenv("SPARK_CARGO_TARGET_DIR", "")
    for text in (BAD, declaration("Skate") + "\n// empty SPARK_CARGO_TARGET_DIR"):
        with pytest.raises(spark.ArgumentError,
                           match=r"^the environment variable SPARK_CARGO_TARGET_DIR is set but empty"):
            spark.compile(text, cache_dir=str(tmp_path))
    assert not list(tmp_path.iterdir())


def test_a_compiled_system_refuses_bad_parameters_and_times_as_argument_errors(cache):
    # As for a registered system: an unknown parameter name and a time that
    # is not finite are bad arguments, refused before the run, by the
    # package and by the module's own functions (whose run failed with a
    # SparkError).
    skate = spark.compile(declaration("Skate"), cache_dir=str(cache))
    with pytest.raises(spark.ArgumentError, match=r"^params key 'bta': system `Skate` has no parameter `bta` "
                                                  r"\(did you mean `beta`\?\); its parameters: m, inertia, g, beta"):
        skate.integrate("gauss", 2, 0.1, 3, q0=[0, 0, 0], v0=[0, 0, 1], params={"bta": 1.0})
    with pytest.raises(spark.ArgumentError, match=r"^t0 = nan is not a finite time"):
        skate.integrate("gauss", 2, 0.1, 3, q0=[0, 0, 0], v0=[0, 0, 1], t0=float("nan"))
    request = {"method": "gauss", "s": 2, "h": 0.1, "steps": 3, "q0": [0, 0, 0], "v0": [0, 0, 1]}
    members = {**request, "q0s": [[0, 0, 0]], "v0s": [[0, 0, 1]]}
    unknown = r"^unknown parameter `bta`; this system declares: m, inertia, g, beta"
    with pytest.raises(spark.ArgumentError, match=unknown):
        skate._integrate({**request, "params": {"bta": 1.0}})
    with pytest.raises(spark.ArgumentError, match=unknown):
        skate._ensemble({**members, "params": {"bta": 1.0}})
    with pytest.raises(spark.ArgumentError, match=r"^parameter `g` = NaN must be finite"):
        skate._integrate({**request, "params": {"g": float("nan")}})
    with pytest.raises(spark.ArgumentError, match=r"^`t0` = inf is not a finite time"):
        skate._ensemble({**members, "t0": float("inf")})
