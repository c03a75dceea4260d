"""``sensor_msgs/msg/Imu`` and ``sensor_msgs/msg/Temperature`` from the MPU-6050's channels
(``mpu6050``: 0-2 acceleration in m/s^2, 3 die temperature in degC, 4-6 angular velocity in
rad/s, all from one burst read: one instant).

No orientation (the chip does not fuse): ``orientation_covariance[0] = -1`` as REP 145 / the
message says; an acceleration or angular velocity with an N/A axis is said the same way (the
vector 0, its covariance's element 0 -1: "disregard the associated estimate"), and a sample
with neither is not published.  The covariances are diagonal, from the datasheet (MPU-6000/6050
product specification rev 3.4) at the range and filter the board runs now (its run-time keys
``accel_g``, ``gyro_dps``, ``dlpf``): noise density squared times the filter's bandwidth
(register map rev 4.2, CONFIG), plus the quantisation of the range's LSB (LSB^2 / 12).  For the
gyro at DLPF 2 (98 Hz) that is 0.005 deg/s/sqrt(Hz) x sqrt(98) = 0.05 deg/s rms, the
datasheet's own total-noise figure.  The axes are the chip's (its frame_id names them; a URDF
places it).
"""

from __future__ import annotations

import math
from typing import Any

from .common import Ctx, StandardMapping, no_channel

IMU = "sensor_msgs/msg/Imu"
TEMPERATURE = "sensor_msgs/msg/Temperature"
G = 9.80665
#: datasheet noise densities: accelerometer 400 ug/sqrt(Hz), gyroscope 0.005 deg/s/sqrt(Hz)
ACCEL_DENSITY = 400e-6 * G  # (m/s^2)/sqrt(Hz)
GYRO_DENSITY = math.radians(0.005)  # (rad/s)/sqrt(Hz)
#: DLPF_CFG 0..6 -> (accelerometer, gyroscope) bandwidth in Hz
DLPF_HZ = ((260, 256), (184, 188), (94, 98), (44, 42), (21, 20), (10, 10), (5, 5))
#: the driver's defaults (board/drivers/mpu6050.py) when the board has no run-time keys
DEFAULTS = {"accel_g": 2, "gyro_dps": 250, "dlpf": 3}


def variances(accel_g: float, gyro_dps: float, dlpf: int) -> tuple[float, float]:
    """(acceleration variance in (m/s^2)^2, angular velocity variance in (rad/s)^2) per axis."""
    a_bw, g_bw = DLPF_HZ[dlpf] if 0 <= dlpf < len(DLPF_HZ) else DLPF_HZ[0]
    accel_lsb = accel_g * G / 32768  # full scale over the int16's half range
    gyro_lsb = math.radians(gyro_dps) / 32768
    accel = ACCEL_DENSITY**2 * a_bw + accel_lsb**2 / 12
    gyro = GYRO_DENSITY**2 * g_bw + gyro_lsb**2 / 12
    return accel, gyro


def build(c: Ctx) -> list[StandardMapping]:
    import numpy as np

    if c.t.chan_count != 7:
        raise ValueError(f"{c.board}/{c.t.name}: Imu wants the mpu6050's seven channels")
    Imu, Vector3 = c.T(IMU), c.T("geometry_msgs/msg/Vector3")
    Quaternion, Temperature = c.T("geometry_msgs/msg/Quaternion"), c.T(TEMPERATURE)
    no_orientation = np.zeros(9, dtype=np.float64)
    no_orientation[0] = -1.0
    no_estimate = no_orientation  # (the same -1 in element 0; never written to)
    cache: dict[tuple[Any, ...], tuple[Any, Any]] = {}

    def covariances() -> tuple[Any, Any]:
        key = tuple(c.setting(k, d) for k, d in DEFAULTS.items())
        got = cache.get(key)
        if got is None:
            a, g = variances(float(key[0]), float(key[1]), int(key[2]))
            got = cache[key] = (np.diag([a] * 3).ravel(), np.diag([g] * 3).ravel())
        return got

    def imu(host_ns: list[int], values: list[Any]) -> bytes | None:
        ax, ay, az, _t, gx, gy, gz = (math.nan if v is None else float(v) for v in values)
        # an N/A (or infinite) axis: the vector is no estimate (covariance[0] = -1, as the message
        # says; never a NaN a consumer would take for a reading); neither vector: no message
        accel_ok = all(map(math.isfinite, (ax, ay, az)))
        gyro_ok = all(map(math.isfinite, (gx, gy, gz)))
        if not (accel_ok or gyro_ok):
            return None
        accel_cov, gyro_cov = covariances()
        if not accel_ok:
            ax = ay = az = 0.0
            accel_cov = no_estimate
        if not gyro_ok:
            gx = gy = gz = 0.0
            gyro_cov = no_estimate
        msg = Imu(
            header=c.header(max(host_ns)),
            orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=0.0),
            orientation_covariance=no_orientation,
            angular_velocity=Vector3(x=gx, y=gy, z=gz),
            angular_velocity_covariance=gyro_cov,
            linear_acceleration=Vector3(x=ax, y=ay, z=az),
            linear_acceleration_covariance=accel_cov,
        )
        return c.cdr(msg, IMU)

    def temperature(host_ns: list[int], values: list[Any]) -> bytes | None:
        if values[3] is None:
            return None
        # (variance 0: unknown; the datasheet gives the sensor's sensitivity, not its accuracy)
        msg = Temperature(header=c.header(host_ns[3]), temperature=float(values[3]), variance=0.0)
        return c.cdr(msg, TEMPERATURE)

    return [
        StandardMapping(IMU, "imu", no_channel, imu, frame=c.frame),
        StandardMapping(TEMPERATURE, "temperature", no_channel, temperature, frame=c.frame),
    ]
