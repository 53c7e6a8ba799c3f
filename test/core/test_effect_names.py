"""The one list of effect names: the catalogue and the simulator share it, their differences are explicit,
and the one --effects grammar serves simulate and diagnose."""

import inspect

import pytest

from quad_modelling.core.diagnosis.catalogue import CATALOGUE, parse_effect_list
from quad_modelling.core.diagnosis.validation import validate
from quad_modelling.core.effect_names import (
    CATALOGUE_EFFECTS,
    DIAGNOSIS,
    DISTURBANCES,
    IDENTIFIABLE_ONLY,
    SIM_DEFAULT_EFFECTS,
    SIM_EFFECTS,
    SIMULATOR,
    SWITCHED_EFFECTS,
    normalise_effect_names,
    parse_effect_names,
)
from quad_modelling.core.sim.params import sim_params_for
from quad_modelling.errors import ConfigError


def test_the_catalogue_and_the_simulator_differ_only_by_the_named_exceptions():
    assert tuple(CATALOGUE) == CATALOGUE_EFFECTS  # the catalogue has one form per name, in that order
    assert len(CATALOGUE_EFFECTS) == 9
    assert set(CATALOGUE) - set(SIM_EFFECTS) == set(IDENTIFIABLE_ONLY) == {"thrust_nonlinearity", "trim_drift"}
    assert set(SIM_EFFECTS) - set(CATALOGUE) == set(DISTURBANCES) == {"wind", "com_offset", "bent_arm"}
    assert SIM_EFFECTS == ("rotor_drag", "battery", "motor_lag", "input_delay", "ground_effect", "gyroscopic",
                           "motor_imbalance", "wind", "com_offset", "bent_arm")
    assert SIM_DEFAULT_EFFECTS == SWITCHED_EFFECTS == SIM_EFFECTS[:-3]
    assert inspect.signature(validate).parameters["effects"].default == SWITCHED_EFFECTS  # the validation withholds every switched catalogue effect


@pytest.mark.parametrize("vehicle", ["linkquad", "crazyflie21"])
def test_the_simulator_has_parameters_for_every_switch(vehicle):
    assert set(sim_params_for(vehicle).effect_parameters(SIM_EFFECTS)) == set(SIM_EFFECTS)


def test_one_grammar_for_simulate_and_diagnose():
    for choice in (SIMULATOR, DIAGNOSIS):
        assert parse_effect_names("none", choice) == ()
        assert parse_effect_names("all", choice) == choice.known
        assert parse_effect_names(None, choice) == parse_effect_names("default", choice)
        # catalogue order whatever the order typed; a blank text and a name typed twice are refused, as identify's
        assert parse_effect_names("motor_lag, battery", choice) == ("battery", "motor_lag")
        with pytest.raises(ConfigError, match=r"--effects '': give none, all, default or a comma list of names"):
            parse_effect_names(" ", choice)
        with pytest.raises(ConfigError, match="motor_lag named more than once; name each once"):
            parse_effect_names("motor_lag, battery,motor_lag", choice)
        for text in ("rotor_drag,", "rotor_drag,,battery"):  # a comma too many was read as nothing
            with pytest.raises(ConfigError, match="an empty name in the list"):
                parse_effect_names(text, choice)
    assert parse_effect_names(None, DIAGNOSIS) == CATALOGUE_EFFECTS
    assert [e.name for e in parse_effect_list("trim_drift,rotor_drag")] == ["rotor_drag", "trim_drift"]
    assert normalise_effect_names(["wind", "battery"], SIMULATOR) == ("battery", "wind")


def test_each_side_rejects_the_names_only_the_other_has():
    with pytest.raises(ConfigError, match="unknown catalogue effect 'wind'.*simulator disturbance"):
        parse_effect_names("battery,wind", DIAGNOSIS)
    with pytest.raises(ConfigError, match="unknown catalogue effect 'com_offset', 'bent_arm'.*simulator disturbance"):
        parse_effect_names("com_offset,bent_arm", DIAGNOSIS)
    with pytest.raises(ConfigError, match="unknown simulator effect 'trim_drift'"):
        parse_effect_names("trim_drift", SIMULATOR)
    with pytest.raises(ConfigError, match="'warp', 'flapping'"):
        normalise_effect_names(["warp", "battery", "flapping"], SIMULATOR)
