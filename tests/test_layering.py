"""Code-shape rules of ARCHITECTURE.md §3 that a machine can check: lint, and dependencies pointing one way."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "holousd"

# domain -> domains it must not import (stages compose domains; domains never import stages or the CLI)
FORBIDDEN = {
    "usd": ("stages", "cli", "physics", "render", "synth", "io", "eval", "graph", "priors"),
    "geometry": ("stages", "cli", "physics", "render", "synth", "eval"),
    "render": ("stages", "cli", "synth"),
    "physics": ("stages", "cli", "render", "synth"),
    "io": ("stages", "cli", "physics", "render"),
    "graph": ("stages", "cli", "physics", "render", "synth", "io", "eval"),
    "eval": ("cli",),  # the benchmark harness composes stages
}


@pytest.mark.parametrize("domain", sorted(FORBIDDEN))
def test_dependencies_point_one_way(domain: str) -> None:
    folder = PACKAGE / domain
    if not folder.is_dir():
        pytest.fail(f"holousd/{domain} is listed in FORBIDDEN but does not exist; update the table")
    pattern = re.compile(r"^\s*(?:from|import)\s+holousd\.(\w+)", re.M)
    offenders = []
    for source in folder.rglob("*.py"):
        for target in pattern.findall(source.read_text()):
            if target in FORBIDDEN[domain]:
                offenders.append(f"{source.relative_to(PACKAGE.parent)} imports holousd.{target}")
    assert not offenders, "\n".join(offenders)


def test_ruff_clean() -> None:
    ruff = shutil.which("ruff") or str(Path(sys.executable).with_name("ruff"))
    result = subprocess.run([ruff, "check", "holousd", "tests"], cwd=PACKAGE.parent, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
