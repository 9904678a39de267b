"""The README's "Using it" snippet runs as written (at a small size)."""
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_using_it_snippet_runs():
    text = (ROOT / "README.md").read_text()
    section = text[text.index("## Using it"):]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    # the same code at 32x24 so that the test stays fast
    code = code.replace("res_x=320, res_y=240", "res_x=32, res_y=24").replace("320 * 240", "32 * 24")
    env = {}
    exec(compile(code, "README.md", "exec"), env)
    assert env["part"].samples is not None
