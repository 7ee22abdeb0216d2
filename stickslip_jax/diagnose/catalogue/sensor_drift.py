"""Sensor drift: the sensor's reading drifts linearly in time."""

from __future__ import annotations

from typing import final

from ...identify.parameters import ParameterSpec
from .base import CatalogueEntry, Probe
from .slots import carry_output_map, sensor_attr, set_value, with_sensor


@final
class SensorDriftEntry(CatalogueEntry):
    """The :class:`~stickslip_jax.model.extensions.SensorOutput`'s drift [m/s] (either
    sign); the refit frees it."""

    name = "sensor_drift"
    slot = "output_map"
    signature = "residual growing with time in every recording"

    def probes(self, act, hints):
        return [Probe("sensor drift", with_sensor,
                      ParameterSpec(sensor_attr("drift"), "linear", 1e-6, "m/s"), 0)]

    def attach(self, act, strength, probe):
        new = set_value(sensor_attr("drift"), strength)(with_sensor(act))
        return new, {"sensor_drift": ParameterSpec(sensor_attr("drift"), "linear",
                                                   probe.strength_scale(strength), "m/s")}

    def carry(self, init, fitted):
        return carry_output_map(init, fitted)
