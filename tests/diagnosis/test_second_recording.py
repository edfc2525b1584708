"""A second recording of a test case's hidden truth, made at another time (the matrix's
``--validate``): the same axis, other moves, another unrecorded load, new noise — on each of
the three plants — and what the held-out gate does with it."""

from __future__ import annotations

import numpy as np
import pytest

from diagnosis.effects import Effect
from diagnosis.engine import diagnose
from diagnosis.matrix import PLANTS, load_plant, run_case
from diagnosis.synthetic import Case


def _case(plant_name: str, effect: Effect | None, seed: int = 7) -> Case:
    plant = load_plant(plant_name)
    cases = plant.cases(seed, 6.0)
    return next(c for c in cases if c.effect is effect)


@pytest.mark.parametrize("plant_name", PLANTS)
def test_another_recording_is_the_same_axis_at_another_time(plant_name: str) -> None:
    """Same columns and length; other moves (the reference differs); deterministic in the
    take; a take below 1 is refused. The concealed torque limit is the first recording's:
    the second recording's torque stays within it (plus its noise) where the plant clips."""
    plant = load_plant(plant_name)
    gen = plant.generate(_case(plant_name, Effect.TORQUE_SATURATION))
    first, second = gen.recording, plant.another(gen, 1)
    assert second.names == first.names and len(second) == len(first)
    assert not np.allclose(second["position_reference"], first["position_reference"])
    again = plant.another(gen, 1)
    assert np.array_equal(again["motor_torque"], second["motor_torque"])
    assert not np.array_equal(plant.another(gen, 2)["motor_torque"], second["motor_torque"])
    limit = gen.truth.control.torque_limit
    assert limit is not None
    noise = 8.0 * float(np.std(np.diff(first["motor_torque"])))
    assert float(np.max(np.abs(second["motor_torque"]))) <= limit + noise
    with pytest.raises(ValueError, match="take 1 or more"):
        plant.another(gen, 0)


@pytest.mark.slow
def test_a_second_recording_refutes_a_load_that_was_only_this_runs() -> None:
    """The third plant's clean rotary recording of seed 12 carries an unrecorded load whose
    mean over the run is 20 mN·m (a random walk of load steps) — the size of the load torque
    its test set conceals (28 mN·m). Alone, the recording names a constant load torque, and
    the explanation asks for a second recording; with a second recording made at another
    time held out, the gate drops it. The concealed load on the same seed stays named."""
    plant = load_plant("third")
    clean = next(c for c in plant.cases(12, 25.0) if c.name == "rotary-none-1")
    gen = plant.generate(clean)
    alone = diagnose(gen.recording, gen.nominal)
    assert alone.left_out == [Effect.CONSTANT_LOAD_TORQUE]
    assert "diagnose --validate` on a recording made at another time" in alone.explanation
    both = diagnose(gen.recording, gen.nominal, validation=plant.another(gen, 1))
    assert both.left_out == []
    dropped = [g.effect for g in both.closed_loop.gate if not g.kept]
    assert Effect.CONSTANT_LOAD_TORQUE in dropped
    loaded = next(c for c in plant.cases(12, 25.0) if c.name == "rotary-constant_load_torque")
    assert run_case(loaded, plant=plant, validate=1).left_out == ["constant_load_torque"]
