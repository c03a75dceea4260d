"""Each part the world feeds, by the board file's ``driver``: what kind of thing it is to the world
and its figures from its datasheet (a world file's ``[parts.NAME]`` may override any of them).
Where a datasheet gives no figure the value is ours and says so; where it gives none for noise
the part reads without noise, the converter's own steps aside.

A world file's figure keys per kind are the keys of FIGURES[kind]; the value's type is the
default's (a float takes an int too)."""

from __future__ import annotations

import math
from typing import Any

#: driver -> the world's kind of part
KINDS = {
    "hbridge": "motor",
    "quadrature": "encoder",
    "servo": "servo",
    "stepper": "stepper",
    "hcsr04": "ranger",
    "srf02": "ranger",
    "vl53l0x": "ranger",
    "sharp_gp2y0a02": "ranger",
    "mpu6050": "imu",
    "qmc5883l": "compass",
    "hmc5883l": "compass",
    "gps_nmea": "gps",
    "battery": "battery",
}

#: per ranger: field of view (deg), nearest and farthest target it reports (m), noise as a
#: standard deviation in metres and as a fraction of the distance
RANGERS: dict[str, dict[str, float]] = {
    # HC-SR04 ("Ultrasonic Ranging Module HC-SR04"): 2 cm-4 m, "measuring angle 15 degree",
    # "ranging accuracy can reach to 3mm" (taken as one standard deviation)
    "hcsr04": {"field_of_view_deg": 15.0, "min_m": 0.02, "max_m": 4.0, "noise_m": 0.003,
               "noise_fraction": 0.0},
    # Devantech SRF02: 16 cm (auto-tuned minimum)-6 m, ~55 degrees (its beam-pattern plot);
    # no noise figure, only its 1 cm resolution, which the part's reading has
    "srf02": {"field_of_view_deg": 55.0, "min_m": 0.16, "max_m": 6.0, "noise_m": 0.0,
              "noise_fraction": 0.0},
    # ST VL53L0X (DS11555): FoV 25 degrees, up to 2 m in its default mode, ranging accuracy
    # 3 % indoors (taken as one standard deviation)
    "vl53l0x": {"field_of_view_deg": 25.0, "min_m": 0.03, "max_m": 2.0, "noise_m": 0.0,
                "noise_fraction": 0.03},
    # Sharp GP2Y0A02YK0F: 20-150 cm specified, its output curve runs on to ~3 m; no beam angle
    # (5 degrees is ours, as ros/standard/ranges.py says) and no noise figure
    "sharp_gp2y0a02": {"field_of_view_deg": 5.0, "min_m": 0.0, "max_m": 3.0, "noise_m": 0.0,
                       "noise_fraction": 0.0},
}  # fmt: skip

G = 9.80665
#: MPU-6000/6050 product specification rev 3.4: accelerometer noise density 400 ug/sqrt(Hz),
#: gyroscope 0.005 deg/s/sqrt(Hz); the register map's DLPF_CFG -> (accel, gyro) bandwidth, Hz
ACCEL_DENSITY_UG = 400.0
GYRO_DENSITY_DPS = 0.005
DLPF_HZ = ((260, 256), (184, 188), (94, 98), (44, 42), (21, 20), (10, 10), (5, 5))
#: the driver's default filter (board/drivers/mpu6050.py)
DLPF_DEFAULT = 3

FIGURES: dict[str, dict[str, Any]] = {
    "ranger": {"field_of_view_deg": 0.0, "min_m": 0.0, "max_m": 0.0, "noise_m": 0.0,
               "noise_fraction": 0.0},
    "imu": {"accel_density_ug": ACCEL_DENSITY_UG, "gyro_density_dps": GYRO_DENSITY_DPS,
            "accel_bias_mg": [0.0, 0.0, 0.0], "gyro_bias_dps": [0.0, 0.0, 0.0],
            "temperature_c": 25.0},
    # QMC5883L datasheet 1.0: RMS noise 2 mG (2 G range, OSR 512); HMC5883L rev E: noise floor
    # 2 milli-gauss (standard deviation of 100 samples)
    "compass": {"noise_mg": 2.0},
    # u-blox NEO-6 (GPS.G6-HW-09005): horizontal position 2.5 m CEP, velocity 0.1 m/s; the error
    # wanders with a correlation time (ours: 60 s; a receiver's error is not white) and up and
    # down twice as far (ours); fix quality, satellites and HDOP as the sentences say them
    "gps": {"cep_m": 2.5, "error_tau_s": 60.0, "vertical_factor": 2.0, "speed_noise_m_s": 0.1,
            "satellites": 8, "hdop": 0.9},
    # Hitec HS-645MG: 0.24 s/60 degrees at 4.8 V
    "servo": {"speed_dps": 250.0},
    # ours: a small stepper's pull-out speed at light load (its torque curve is the motor's)
    "stepper": {"speed_rev_s": 5.0},
    "encoder": {"counts_per_rev": 0.0},  # (0: the board file's counts_per_rev, else [drive]'s)
    "motor": {},
    "battery": {},
}  # fmt: skip


def figures(driver: str, given: dict[str, Any]) -> dict[str, Any]:
    """A part's figures: its kind's and its datasheet's, then what the world file gives."""
    kind = KINDS[driver]
    out = dict(FIGURES[kind])
    if kind == "ranger":
        out.update(RANGERS[driver])
    out.update(given)
    return out


def imu_sigmas(fig: dict[str, Any], dlpf: int) -> tuple[float, float]:
    """(accelerometer m/s^2, gyroscope rad/s) standard deviation per axis: the noise density
    times the square root of the filter's bandwidth."""
    a_bw, g_bw = DLPF_HZ[dlpf] if 0 <= dlpf < len(DLPF_HZ) else DLPF_HZ[0]
    accel = float(fig["accel_density_ug"]) * 1e-6 * G * math.sqrt(a_bw)
    gyro = math.radians(float(fig["gyro_density_dps"])) * math.sqrt(g_bw)
    return accel, gyro


def cep_sigma(cep_m: float) -> float:
    """The standard deviation per axis of a circular normal error whose CEP (the radius half
    the fixes fall within) is ``cep_m``: CEP = sigma sqrt(2 ln 2)."""
    return cep_m / math.sqrt(2 * math.log(2))
