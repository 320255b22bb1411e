"""The colour model, IK priors and pose database files of `mocap shirt` (``--colour-model``, ``--priors``,
``--database``): the first two read back what they saved, and a wrong file given for one (another's, a picture, a
truncated archive) is an InputFileError naming the file. They were numpy's KeyError and pickle ValueError
tracebacks, or "missing array 'means is not a file in the archive'"."""

from __future__ import annotations

import numpy as np
import pytest

from mocap.errors import InputFileError
from mocap.shirt.colour_model import ColourModel
from mocap.shirt.ik import IKPriors
from mocap.shirt.kinematics import UPPER_NV
from mocap.shirt.pose_database import PoseDatabase


@pytest.fixture()
def files(tmp_path):
    rng = np.random.default_rng(3)
    colours = ColourModel(rng.random((2, 3)), np.stack([np.eye(3) * 0.01] * 2), ("red", "green"))
    a = rng.normal(size=(20, 2, 2))
    priors = IKPriors(np.einsum("nij,nkj->nik", a, a) + np.eye(2), np.full(UPPER_NV, 0.1), np.full(UPPER_NV, 0.2), 40)
    colours.save(tmp_path / "colour_model.npz")
    priors.save(tmp_path / "ik_priors.npz")
    return colours, priors, tmp_path


def test_each_reads_back_what_it_saved(files):
    colours, priors, d = files
    back = ColourModel.load(d / "colour_model.npz")
    np.testing.assert_array_equal(back.means, colours.means)
    np.testing.assert_array_equal(back.covariances, colours.covariances)
    assert back.names == colours.names
    p = IKPriors.load(d / "ik_priors.npz")
    np.testing.assert_array_equal(p.centroid_cov, priors.centroid_cov)
    np.testing.assert_array_equal(p.blend_std, priors.blend_std)
    assert p.n_frames == 40


def test_a_wrong_file_is_one_error_naming_it(files):
    _, _, d = files
    (d / "picture.png").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(64))
    whole = (d / "colour_model.npz").read_bytes()
    (d / "truncated.npz").write_bytes(whole[: len(whole) // 2])
    cases = [
        (IKPriors.load, d / "colour_model.npz", "not an IK priors file: no array centroid_cov, blend_std, motion_std, n_frames"),
        (ColourModel.load, d / "ik_priors.npz", "not a colour model: no array means, covariances, names"),
        (ColourModel.load, d / "picture.png", "not a colour model: not a .npz archive"),
        (IKPriors.load, d / "picture.png", "not an IK priors file: not a .npz archive"),
        (ColourModel.load, d / "truncated.npz", "colour model"),
        (IKPriors.load, d / "missing.npz", "IK priors file not found"),
        (PoseDatabase.load, d / "picture.png", "not a pose database: not a .npz archive"),
        (PoseDatabase.load, d / "colour_model.npz", "not a pose database: no array tiny, hinges"),
    ]
    for load, path, says in cases:
        with pytest.raises(InputFileError) as err:
            load(path)
        assert err.value.path == path and says in str(err.value) and "\n" not in str(err.value), str(err.value)
