"""Small truths of the reports (review s35, finding 14): the eigenaxis/learned time ratio to 2
significant digits (``:.0f`` printed 1.30 as "1×"), and train.py's docstring lists the files a
run directory really holds (it named a MODEL_CARD.md that is model.md)."""
import os
import re

import pytest

from training.warmstart import train as train_module
from training.warmstart.evaluate import markdown


def _summary(ratio):
    return {"family": "full-attitude", "n": 2, "seed": 1, "model": "m.npz", "baseline_n": 2, "workers": 1,
            "inference_s_median": 4e-5, "nit_ratio_eigenaxis_over_learned": 9.5,
            "time_ratio_eigenaxis_over_learned": ratio}


@pytest.mark.parametrize("ratio, text", [(1.30, "1.3"), (0.4, "0.40"), (0.043, "0.043"), (16.2, "16"), (134.0, "130")])
def test_the_time_ratio_has_two_significant_digits(ratio, text):
    assert f"and {text}× its time (median ratio)" in markdown(_summary(ratio))


def test_the_docstring_lists_the_files_of_a_run_directory(tmp_path):
    pytest.importorskip("torch")
    data = os.path.join(os.path.dirname(__file__), "data", "full-attitude-small.jsonl")
    train_module.train([data], tmp_path, epochs=1, progress_bar=False)
    written = {f for f in os.listdir(tmp_path) if f != "checkpoints"} | {"checkpoints/epoch_NNNN.pt"}
    assert os.listdir(tmp_path / "checkpoints") == ["epoch_0001.pt"]
    doc = train_module.__doc__.split("Run directory:")[1]
    named = set(re.findall(r"``([\w./]+\.\w+)``", doc))
    assert named == written
