"""The README's quickstart: its two commands are the ones CI and users run."""

import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).parent.parent


def _quickstart_blocks():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    quick = text.split("## Quickstart", 1)[1].split("\n## ", 1)[0]
    return [b.strip() for b in re.findall(r"```bash\n(.*?)```", quick, flags=re.S)]


def test_quickstart_has_the_two_commands_and_ci_runs_the_second():
    blocks = _quickstart_blocks()
    assert len(blocks) == 2
    setup_and_demo, setup_and_tests = blocks
    assert "pip install -e ." in setup_and_demo and "calib demo" in setup_and_demo
    assert "pip install" in setup_and_tests and '-e ".[test]"' in setup_and_tests
    assert "pytest" in setup_and_tests
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert "blocks[1]" in ci and "README.md" in ci  # .ci/run extracts and runs block 2


def test_the_tests_started_first_for_ci_exist():
    """The longest tests, started first so that CI spreads them over both workers
    (``tests/conftest.py``), are named by ids the collection has, and come first in it."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("_ci_conftest", ROOT / "tests" / "conftest.py")
    conftest = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(conftest)
    done = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q",
                           str(ROOT / "tests")], cwd=ROOT, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    ids = [line.split("::")[-1] for line in done.stdout.splitlines() if "::" in line]
    assert ids[:len(conftest._FIRST)] == list(conftest._FIRST), ids[:6]


@pytest.mark.slow
def test_quickstart_main_job_runs(tmp_path):
    """The README's main job (after its set-up) in this environment: ``calib demo``."""
    demo = _quickstart_blocks()[0].split("&&")[-1].strip()
    args = shlex.split(demo)
    assert Path(args[0]).name == "calib" and args[1] == "demo"
    done = subprocess.run([sys.executable, "-m", "calib", *args[1:], "--json"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=1500)
    assert done.returncode == 0, done.stderr[-2000:]
    out = tmp_path / args[args.index("--out") + 1]
    for name in ("summary.md", "parameters.csv", "parameters.inp", "parameters.feb",
                 "rates.png", "fit_overview.png", "discover/discover.json"):
        assert (out / name).exists(), name
    import json

    summary = json.loads(done.stdout)
    assert summary["cycles"] == 54
    assert len(summary["parameters"]) == 6
    assert summary["discovery"]["effect"] == "rate_dependence"
