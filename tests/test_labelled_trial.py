"""``mocap.labelled_trial``: a labelled trial (C3D, TRC, CSV) read as the rigid-cluster labelling model
of a capture without a skeleton, and the files it refuses."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocap.errors import InputFileError
from mocap.exports import write_c3d, write_csv, write_trc
from mocap.labelled_trial import load_labelled_trial
from mocap.types import Trajectories

# two rigid bodies, five markers each (metres, body frame): a marker's four neighbours are its body's others
_BODY_A = np.array([[0.0, 0.0, 0.0], [0.12, 0.0, 0.0], [0.0, 0.09, 0.0], [0.03, 0.02, 0.11], [0.1, 0.08, 0.04]])
_BODY_B = np.array([[0.0, 0.0, 0.0], [0.1, 0.02, 0.0], [0.0, 0.14, 0.03], [0.05, 0.05, 0.08], [0.09, 0.12, 0.0]])
NAMES = ["A1", "A2", "A3", "A4", "A5", "B1", "B2", "B3", "B4", "B5"]


def _pose(rng: np.random.Generator, body: np.ndarray, centre: np.ndarray) -> np.ndarray:
    return Rotation.random(random_state=rng).apply(body) + centre + rng.normal(0.0, 0.05, 3)


def _trial(frames: int = 40, seed: int = 0) -> Trajectories:
    """Two bodies moving independently (a body's markers rigid together, the bodies not)."""
    rng = np.random.default_rng(seed)
    xyz = np.stack([np.concatenate([_pose(rng, _BODY_A, np.array([0.0, 0.0, 1.0])),
                                    _pose(rng, _BODY_B, np.array([0.3, 0.0, 1.0]))]) for _ in range(frames)])
    return Trajectories(NAMES, xyz, np.arange(frames) / 100.0)


@pytest.mark.parametrize("suffix", [".c3d", ".trc", ".csv"])
def test_each_format_gives_a_model_that_predicts_a_marker_from_its_body(tmp_path, suffix) -> None:
    """A marker hidden in a new pose, in another world frame than the trial's, is predicted from its own
    body's markers to within the files' rounding (C3D stores float32 millimetres)."""
    path = tmp_path / f"trial{suffix}"
    {".c3d": write_c3d, ".trc": write_trc, ".csv": write_csv}[suffix](path, _trial())
    trial = load_labelled_trial(path, NAMES)
    assert trial.model.labels == NAMES and trial.missing == () and trial.frames == 40
    for m in (1, 7):
        # a marker's neighbours are the markers whose distances to it do not vary: its own body's
        same = set(range(5)) if m < 5 else set(range(5, 10))
        assert set(trial.model.neighbours[m].tolist()) == same - {m}, trial.model.neighbours[m]
    rng = np.random.default_rng(7)
    pos = np.concatenate([_pose(rng, _BODY_A, np.array([5.0, -2.0, 0.3])), _pose(rng, _BODY_B, np.array([5.4, -2.0, 0.3]))])
    for m in (1, 7):
        seen = pos.copy()
        seen[m] = np.nan
        np.testing.assert_allclose(trial.model.predict(seen, np.array([m]))[0], pos[m], atol=2e-4)


def test_template_markers_the_trial_lacks_are_reported_and_the_order_is_the_templates(tmp_path) -> None:
    path = write_trc(tmp_path / "trial.trc", _trial())
    names = ["B2", "A1", "XX", "A2", "A3", "A4"]
    trial = load_labelled_trial(path, names)
    assert trial.model.labels == ["B2", "A1", "A2", "A3", "A4"]
    assert trial.missing == ("XX",)


def test_files_it_refuses_name_the_file_and_the_fix(tmp_path) -> None:
    with pytest.raises(InputFileError, match=r"trial\.txt: file type '\.txt'.*\.c3d, \.trc, \.csv"):
        load_labelled_trial(tmp_path / "trial.txt", NAMES)
    with pytest.raises(InputFileError, match=r"nothere\.c3d: no such file"):
        load_labelled_trial(tmp_path / "nothere.c3d", NAMES)
    path = write_trc(tmp_path / "other.trc", _trial())
    with pytest.raises(InputFileError, match=r"other\.trc: holds 2 of the template's 3 markers \(A1, B1;"):
        load_labelled_trial(path, ["A1", "B1", "ZZ"])
    still = write_csv(tmp_path / "still.csv", _trial(frames=1))
    with pytest.raises(InputFileError, match=r"still\.csv: has 1 frame with 3 or more.*range of motion"):
        load_labelled_trial(still, NAMES)
    bad = tmp_path / "bad.c3d"
    bad.write_bytes(b"\x00not a c3d")
    with pytest.raises(InputFileError, match=r"bad\.c3d"):
        load_labelled_trial(bad, NAMES)


def _real_captures(shared: Path) -> list[Path]:
    return sorted((shared / "c3d").glob("*.c3d")) + sorted((shared / "trc").glob("*.trc"))


def test_every_real_capture_reads_as_a_trial_whose_gates_hold_its_own_motion(shared_data) -> None:
    """Every C3D and TRC of the shared data (six systems, gaps, static trials) as a labelled trial of its own
    markers: the model predicts 95 % or more of the sampled points within their gates (the gates are learned
    from the same motion: a reader or loader that shuffled, rescaled or dropped points would break this),
    and the two standing trials, only they, are flagged static."""
    from mocap.exports import read_c3d, read_trc

    files = _real_captures(shared_data)
    assert len(files) == 12, [f.name for f in files]
    static = []
    for path in files:
        labels = list((read_c3d if path.suffix == ".c3d" else read_trc)(path).labels)
        trial = load_labelled_trial(path, labels)
        assert trial.missing == () and np.isfinite(trial.model.gate_m).all(), path.name
        xyz = (read_c3d if path.suffix == ".c3d" else read_trc)(path).xyz
        inside = []
        for f in range(0, len(xyz), max(1, len(xyz) // 40)):
            d = np.linalg.norm(trial.model.predict(xyz[f]) - xyz[f], axis=1)
            ok = np.isfinite(d)
            inside.append(d[ok] <= trial.model.gate_m[ok])
        assert np.concatenate(inside).mean() >= 0.95, path.name
        if trial.is_static:
            static.append(path.name)
    assert static == ["Res16bits.c3d", "Sample_Static.c3d"]
