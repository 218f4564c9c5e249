"""Issue 36 must-show 3 on iiwa7_close: the first day with the README's defaults (first_day.py)."""
from first_day import run_the_first_day


def test_the_first_day_with_the_readme_defaults_succeeds_on_iiwa7(tmp_path):
    run_the_first_day('iiwa7_close', tmp_path)
