"""The README's Python example runs as written and reconstructs its scene."""

import re
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_python_example_runs(capsys):
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    assert blocks, "the README has no Python example"
    namespace: dict = {}
    exec(compile(blocks[0], "README.md", "exec"), namespace)  # noqa: S102 - our own README
    assert namespace["cube"].shape == namespace["truth"].shape
    assert namespace["info"]["metrics"]["psnr"] > 25.0
    assert "dB" in capsys.readouterr().out
