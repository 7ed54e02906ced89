"""The crates from crates.io a `spark.compile` build depends on resolve
with the features the wheel's build gives them (`spark._compile.FEATURE_PINS`),
so that a target directory shared with the wheel's build keeps them compiled."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

from spark import _native
from spark._compile import _crate

def features(manifest: Path) -> set[str]:
    """`cargo tree`'s crates of ``manifest``'s build (normal and build
    dependencies), each with its version and features; the path crates,
    which cargo compiles for each workspace apart, left out."""
    done = subprocess.run(
        ["cargo", "tree", "--offline", "--manifest-path", str(manifest), "-e", "normal,build", "--prefix", "none",
         "-f", "{p} {f}"],
        capture_output=True, text=True, check=True,
    )
    return {re.sub(r" \(\*\)$", "", line) for line in done.stdout.splitlines() if line and " (/" not in line}


@pytest.mark.skipif(shutil.which("cargo") is None, reason="needs cargo")
def test_a_declarations_crate_resolves_the_crates_io_crates_with_the_wheels_features(tmp_path):
    source = Path(_native.source_dir())
    manifest, lib = _crate(source, "_spark_pins_0", "Pins", 1, 0, "")
    (tmp_path / "Cargo.toml").write_text(manifest)
    (tmp_path / "lib.rs").write_text(lib)
    shutil.copyfile(source / "Cargo.lock", tmp_path / "Cargo.lock")
    declaration = features(tmp_path / "Cargo.toml")
    wheel = features(source / "python" / "Cargo.toml")
    assert len(declaration) > 30, declaration
    assert declaration <= wheel, sorted(declaration - wheel)
