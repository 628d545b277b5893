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
    "usd": ("stages", "cli", "physics", "render", "synth", "io", "eval", "graph", "priors", "batch"),
    "geometry": ("stages", "cli", "physics", "render", "synth", "eval", "batch"),
    "render": ("stages", "cli", "synth", "batch"),
    "physics": ("stages", "cli", "render", "synth", "batch"),
    "io": ("stages", "cli", "physics", "render", "batch"),
    "graph": ("stages", "cli", "physics", "render", "synth", "io", "eval", "batch"),
    "eval": ("cli",),  # the benchmark harness composes stages (and runs them on batch's engine)
    "batch": ("cli",),
    "view": ("cli", "eval", "batch"),  # the viewer sits above the stages, beside eval and batch
    "priors": ("stages", "cli", "eval", "batch"),  # proposers and E_obs: the search stage composes them
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


def _module_imports(folder: Path) -> dict[str, set[str]]:
    """Module name -> sibling modules it imports (``from ._x import``, ``from . import _x``, ``holousd.<pkg>._x``),
    at module level or inside functions alike: a lazy import still closes a circle."""
    modules = {p.stem: p for p in folder.glob("*.py")}
    package = folder.name
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        text = path.read_text()
        found = set(re.findall(r"^\s*from\s+\.(\w+)\s+import", text, re.M))
        found |= set(re.findall(r"^\s*from\s+holousd\." + package + r"\.(\w+)\s+import", text, re.M))
        for group in re.findall(r"^\s*from\s+\.\s+import\s+([\w, ]+)", text, re.M):
            found |= {g.strip() for g in group.split(",")}
        graph[name] = {m for m in found if m in modules and m != name}
    return graph


@pytest.mark.parametrize("domain", ["physics", "geometry", "render"])
def test_no_import_circles_inside_a_domain(domain: str) -> None:
    graph = _module_imports(PACKAGE / domain)
    graph.pop("__init__", None)
    for deps in graph.values():
        deps.discard("__init__")
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                cycle = stack[stack.index(nxt) :] + [nxt]
                pytest.fail(f"holousd/{domain} import circle: {' -> '.join(cycle)}")
            if nxt not in state:
                visit(nxt)
        stack.pop()
        state[node] = 2

    for node in sorted(graph):
        if node not in state:
            visit(node)


def test_render_kernels_never_import_eval() -> None:
    """The appearance fit's loss is the render domain's own (``holousd.render._ssim``); only the render CLI,
    which offers the appearance benchmark, reaches into eval."""
    pattern = re.compile(r"^\s*(?:from|import)\s+holousd\.eval\b", re.M)
    sources = [p for p in (PACKAGE / "render").glob("*.py") if p.name != "_cli.py"]
    offenders = [p.name for p in sources if pattern.search(p.read_text())]
    assert not offenders, offenders


def test_stages_never_import_what_sits_above_them() -> None:
    """eval, view and batch sit above the stages (ARCHITECTURE.md §3); only the stages' command-line glue, which
    offers ``eval`` and ``bench``, reaches up."""
    pattern = re.compile(r"^\s*(?:from|import)\s+holousd\.(eval|batch|view)\b", re.M)
    sources = [p for p in (PACKAGE / "stages").glob("*.py") if not p.name.endswith("_cli.py")]
    offenders = [p.name for p in sources if pattern.search(p.read_text())]
    assert not offenders, offenders
