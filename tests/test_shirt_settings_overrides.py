"""A scenario sets the shirt tracker's settings for both methods (``[shirt_pipeline.settings]``): ablations by
``simbench run``/``compare``/``sweep``, checked when the scenario loads."""

from __future__ import annotations

import pytest

from mocap.errors import MocapInputError
from mocap.shirt.settings import ShirtPipelineParams
from simbench.errors import ScenarioError
from simbench.pipelines.shirt import tracker_params
from simbench.scenario import load_scenario

OFFICE = "scenarios/shirt_office.toml"


def test_the_settings_reach_the_full_method_and_the_baseline_derived_from_it():
    sc = load_scenario(OFFICE, overrides={"shirt_pipeline.settings.adaptive_white_balance": False,
                                          "shirt_pipeline.settings.wb_smoothing": 0.1,
                                          "shirt_pipeline.settings.lock_on_yaws": 4})
    full = tracker_params(sc)
    assert (full.adaptive_white_balance, full.wb_smoothing, full.lock_on_yaws) == (False, 0.1, 4)
    assert full.pose_prior and full.keep_classification and full.hand_constraints
    base = full.baseline()
    assert (base.pose_prior, base.adaptive_white_balance, base.wb_smoothing, base.lock_on_yaws) == (False, False, 0.1, 4)
    # nothing set: the defaults, as before the field existed
    assert tracker_params(load_scenario(OFFICE)) == ShirtPipelineParams(keep_classification=True)


def test_a_scenario_without_settings_serialises_and_hashes_without_them():
    plain = load_scenario(OFFICE)
    assert "settings" not in plain.model_dump(mode="json")["shirt_pipeline"]
    assert plain.with_overrides({"shirt_pipeline.settings": {}}).content_hash() == plain.content_hash()
    ablated = plain.with_overrides({"shirt_pipeline.settings.pose_prior": False})
    assert ablated.model_dump(mode="json")["shirt_pipeline"]["settings"] == {"pose_prior": False}
    assert ablated.content_hash() != plain.content_hash()


@pytest.mark.parametrize("name, value, says", [
    ("pose_priors", False, "shirt_pipeline.settings.pose_priors: not a setting of the shirt tracker; did you mean 'pose_prior'?"),
    ("pose_prior", 1, "shirt_pipeline.settings.pose_prior=1: must be true or false"),
    ("neighbours", 2.5, "shirt_pipeline.settings.neighbours=2.5: must be a whole number"),
    ("wb_smoothing", True, "shirt_pipeline.settings.wb_smoothing=True: must be a number"),
    ("wb_smoothing", 0, "ShirtPipelineParams.wb_smoothing=0.0: must be in (0, 1]"),
    # strings, as `--set` leaves what is not TOML: the setting's own type is named, not a member of a union
    ("adaptive_white_balance", "False", "shirt_pipeline.settings.adaptive_white_balance='False': must be true or false"),
    ("prior_c", "abc", "shirt_pipeline.settings.prior_c='abc': must be a number"),
    ("hand_constraints", False, "hand_constraints is not set here: use shirt_pipeline.hands"),
    ("keep_classification", False, "keep_classification is not set here"),
])
def test_a_bad_setting_is_refused_when_the_scenario_loads_in_one_line_naming_it(name, value, says):
    with pytest.raises(ScenarioError) as err:
        load_scenario(OFFICE, overrides={f"shirt_pipeline.settings.{name}": value})
    message = str(err.value)
    assert "\n" not in message and "shirt_office.toml" in message and "shirt_pipeline.settings" in message
    assert says in message and ".bool" not in message


def test_with_settings_takes_an_int_for_a_float_and_checks_ranges_as_construction_does():
    p = ShirtPipelineParams().with_settings({"wb_smoothing": 1, "pose_prior": False})
    assert p.wb_smoothing == 1.0 and isinstance(p.wb_smoothing, float) and not p.pose_prior
    assert ShirtPipelineParams().with_settings({}) == ShirtPipelineParams()
    with pytest.raises(MocapInputError, match=r"^ShirtPipelineParams.steady_motion_scale=11.0: must be in \(0, 10\]"):
        ShirtPipelineParams().with_settings({"steady_motion_scale": 11})
