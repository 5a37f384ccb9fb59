"""The README's measured figures are exactly what the committed benchmark records say."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_readme_results_blocks_match_the_committed_records():
    check = subprocess.run([sys.executable, "scripts/readme_results.py", "--check"], cwd=ROOT,
                           capture_output=True, text=True)
    assert check.returncode == 0, check.stderr


def test_a_stale_block_is_detected(tmp_path):
    sys.path.insert(0, str(ROOT / "scripts"))
    try:
        import readme_results
    finally:
        sys.path.pop(0)
    stale = "<!-- results:simulator-speed -->\n| typed by hand |\n<!-- /results:simulator-speed -->\n"
    assert readme_results.render(stale) != stale
    assert readme_results.render(readme_results.render(stale)) == readme_results.render(stale)
