"""docs/course.ipynb, the course as a notebook, executed headless as a student would run it
(with a small training budget): its outputs hold the curves inline and the verdict."""

from __future__ import annotations

import base64
from pathlib import Path

import pytest

NOTEBOOK = Path(__file__).resolve().parent.parent / "docs" / "course.ipynb"


@pytest.mark.slow
def test_course_notebook_runs_and_shows_the_curves_the_verdict_and_the_gif(tmp_path, monkeypatch):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    monkeypatch.setenv("JAXCART_COURSE_TIMESTEPS", "4096")  # 2 iterations of 2048 steps
    monkeypatch.delenv("XLA_FLAGS", raising=False)  # the notebook chooses its devices
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    client = nbclient.NotebookClient(
        notebook, timeout=300, kernel_name="python3", resources={"metadata": {"path": tmp_path}}
    )
    client.execute()

    outputs = [o for cell in notebook.cells if cell.cell_type == "code" for o in cell.outputs]
    text = "".join(o.get("text", "") for o in outputs if o.output_type == "stream")
    data = [o.data for o in outputs if o.output_type in ("display_data", "execute_result")]
    assert "random policy: mean" in text
    # tqdm.auto's bar is a Jupyter widget (ipywidgets is in the test extra), not text lines
    assert any("application/vnd.jupyter.widget-view+json" in d for d in data)
    assert "verdict: " in text and ("solved, all 20" in text or "of 20 greedy" in text)
    png = [base64.b64decode(d["image/png"]) for d in data if "image/png" in d]
    gif = [base64.b64decode(d["image/gif"]) for d in data if "image/gif" in d]
    assert png and png[0].startswith(b"\x89PNG") and len(png[0]) > 20_000  # the curves
    assert gif and gif[0].startswith(b"GIF8")
    (run_dir,) = (tmp_path / "runs").iterdir()  # what the notebook trained, where it said
    assert (run_dir / "curves.png").is_file() and (run_dir / "balance.gif").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["runs"]  # nothing else left here
