"""Sensor delay: the sensor reads the position late."""

from __future__ import annotations

from typing import final

from ...identify.parameters import ParameterSpec
from .base import CatalogueEntry, Probe
from .slots import carry_output_map, sensor_attr, set_value, with_sensor


@final
class SensorDelayEntry(CatalogueEntry):
    """The :class:`~stickslip_jax.model.extensions.SensorOutput`'s delay [s] (≥ 0);
    the refit frees it."""

    name = "sensor_delay"
    slot = "output_map"
    signature = ("residual proportional to the output's rate: largest at edges, all "
                 "regimes alike")

    def probes(self, act, hints):
        return [Probe("sensor delay", with_sensor,
                      ParameterSpec(sensor_attr("delay"), "linear", 1e-5, "s"), +1)]

    def attach(self, act, strength, probe):
        new = set_value(sensor_attr("delay"), max(strength, 1e-6))(with_sensor(act))
        return new, {"sensor_delay": ParameterSpec(sensor_attr("delay"), "log", 1.0, "s")}

    def carry(self, init, fitted):
        return carry_output_map(init, fitted)
