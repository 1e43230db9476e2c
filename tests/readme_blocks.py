"""Run the first ```python block under a heading of the README (or of another page, e.g. a docs/ page)
verbatim (a FutureWarning is an error) and return what it printed."""

import contextlib
import io
import re
import warnings
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def run_python_block(heading: str, page: Path = README) -> str:
    section = page.read_text()
    section = section[section.index(heading):]
    block = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    out = io.StringIO()
    with contextlib.redirect_stdout(out), warnings.catch_warnings():
        warnings.simplefilter("error", FutureWarning)  # a README block uses no deprecated API
        exec(compile(block, page.name, "exec"), {})
    return out.getvalue()
