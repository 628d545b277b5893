"""The README's main command, exactly as a new user types it, from a fresh working folder."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _setup_commands() -> list[str]:
    """The commands of the README's 'Set up and try it' block, in order."""
    readme = (REPO / "README.md").read_text()
    section = readme.split("## Set up and try it", 1)[1]
    block = re.search(r"```bash\n(.*?)```", section, re.S)
    assert block, "the README's 'Set up and try it' section lost its bash block"
    return [line.strip() for line in block.group(1).splitlines() if line.strip() and not line.startswith("#")]


def test_readme_main_command_runs_from_a_fresh_folder(tmp_path: Path) -> None:
    commands = _setup_commands()
    assert commands[0].startswith("pip install torch==2.13.0")  # the install this test environment already did
    main_command = commands[1]
    argv = shlex.split(main_command)
    assert argv[0] == "holousd"
    executable = Path(sys.executable).with_name("holousd")
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    run = subprocess.run([str(executable), *argv[1:]], cwd=tmp_path, capture_output=True, text=True, env=env,
                         timeout=1500)  # fmt: skip
    assert run.returncode == 0, f"{main_command!r} failed:\n{run.stderr[-3000:]}"
    assert "Traceback" not in run.stderr
    out = tmp_path / "holousd_demo"  # the demo's default --out, relative to the working folder
    report = out / "report.html"
    assert f"demo report: {report}" in run.stdout
    assert report.is_file() and "Stable%" in report.read_text()
    layers = sorted(p.name for p in (out / "recon").glob("*.usda"))
    assert layers == [
        "00_observe.usda", "10_fit.usda", "15_search.usda", "20_physics.usda", "30_appearance.usda", "scene.usda"
    ]  # fmt: skip
    assert not list(tmp_path.rglob("recon/recon"))
