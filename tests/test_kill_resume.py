"""``jsrte train`` killed with SIGKILL while its worker processes sample the shapes' SDF: no
worker outlives it, and running the command again gives the model of an uninterrupted run.

(``tests/test_fit_many.py`` does the same for ``jsrte fit-many``.)
"""

import os
import subprocess
import sys

import pytest
import torch

from process_tree import kill_all, sigkill_leaves_no_orphans, wait_for_descendants

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")

TRAIN = ["train", "--shapes", "3", "--samples", "8000", "--steps", "4", "--batch-shapes", "2", "--points", "64",
         "--checkpoint-every", "2", "--no-progress", "--threads", "1"]


def test_train_killed_while_sampling_leaves_no_orphans_and_reruns_to_the_same_model(tmp_path, run_cli):
    from jsrte.model.checkpoint import load_model
    from jsrte.model.train import MODEL_NAME, STATE_NAME

    killed = tmp_path / "killed"
    proc = subprocess.Popen([sys.executable, "-m", "jsrte.cli", *TRAIN, "--out", str(killed)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env=dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path)))
    try:
        workers = wait_for_descendants(proc.pid, 2, timeout=120)  # the sampling pool
        assert workers, "the sampling workers never started"
        assert not (killed / STATE_NAME).exists()  # still sampling
        sigkill_leaves_no_orphans(proc, workers)
    finally:
        proc.kill()
        kill_all(wait_for_descendants(proc.pid, 0, 0))

    code, _, err = run_cli([*TRAIN, "--out", killed])  # no checkpoint yet: the same command again
    assert code == 0, err
    code, _, err = run_cli([*TRAIN, "--out", tmp_path / "straight"])
    assert code == 0, err
    again, straight = load_model(killed / MODEL_NAME), load_model(tmp_path / "straight" / MODEL_NAME)
    assert torch.equal(again.codes, straight.codes)
    for a, b in zip(again.decoder.state_dict().values(), straight.decoder.state_dict().values(), strict=True):
        assert torch.equal(a, b)
