"""Every Python snippet of docs/guides/python.md runs, in order, in one namespace, with run_dir a run folder."""
import os
import re

from conftest import SOURCE


def test_python_guide_snippets_run(run_folder, capsys, monkeypatch):
    text = open(os.path.join(SOURCE, "docs", "guides", "python.md")).read()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert len(blocks) >= 5
    namespace = {"run_dir": str(run_folder)}
    monkeypatch.chdir(SOURCE)  # the guide's paths are the source tree's
    for i, code in enumerate(blocks):
        exec(compile(code, "docs/guides/python.md python block %d" % (i + 1), "exec"), namespace)
    out = capsys.readouterr().out
    assert "episodes ended:" in out and "returns" in out
