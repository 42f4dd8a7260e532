"""The README's TorchRL example runs as written."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def _example() -> str:
    text = README.read_text()
    block = re.search(r"<!-- example:start -->\s*```python\n(.*?)```\s*<!-- example:end -->", text, re.S)
    assert block, "README example markers not found"
    return block.group(1)


def test_readme_example_is_short():
    assert len(_example().strip().splitlines()) <= 25


def test_readme_example_runs(tmp_path):
    script = tmp_path / "example.py"
    script.write_text(_example())
    result = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    returns = [float(m) for m in re.findall(r"update \d: mean return (-?\d+\.\d+)", result.stdout)]
    assert len(returns) == 3 and all(-17 < r < 0 for r in returns), result.stdout
