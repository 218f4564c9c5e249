"""Issue 36 must-show 3 on ur10e_close: the first day with the README's defaults (first_day.py)."""
from first_day import run_the_first_day


def test_the_first_day_with_the_readme_defaults_succeeds_on_ur10e(tmp_path):
    run_the_first_day('ur10e_close', tmp_path)
