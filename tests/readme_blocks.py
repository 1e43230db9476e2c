"""Run the first ```python block under a README heading verbatim (a FutureWarning is an error) and return
what it printed."""

import contextlib
import io
import re
import warnings
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def run_python_block(heading: str) -> str:
    section = README.read_text()
    section = section[section.index(heading):]
    block = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    out = io.StringIO()
    with contextlib.redirect_stdout(out), warnings.catch_warnings():
        warnings.simplefilter("error", FutureWarning)  # a README block uses no deprecated API
        exec(compile(block, "README.md", "exec"), {})
    return out.getvalue()
