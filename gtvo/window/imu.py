"""The IMU's one owner in the window: gravity, every keyframe's velocity and bias, and the factors
between consecutive keyframes (docs/imu.md, "In the window").

* **Initialisation** (:meth:`ImuWindow.try_initialise`), once the keyframes seen so far span
  ``init_seconds`` of IMU readings (VINS-Fusion's visual-inertial alignment, with the scale known
  from stereo):

  - *static* (the keyframes moved less than ``static_translation`` and ``static_rotation_deg``):
    gravity is the mean specific force turned into the world (``g = -R_world_imu mean(f)``, scaled
    to ``gravity``), the gyro bias the mean angular rate, velocities zero;
  - *moving*: the gyro bias from the keyframes' relative rotations against the preintegrated
    ones (least squares on ``Log(dR_imu^T R_i^T R_j) = J_bg db_g``), then gravity and every
    keyframe's IMU velocity from the preintegrated velocity and position changes
    (``v_j = v_i + g dt + R_i dv``, ``p_j = p_i + v_i dt + g dt^2/2 + R_i dp``: linear), gravity
    rescaled to ``gravity`` and the velocities solved again with it held; refused, and tried again at
    the next keyframe, when the gravity found is more than :data:`GRAVITY_CHECK` off in magnitude or
    its direction's sigma above :data:`MAX_INIT_SIGMA_DEG` (the keyframes used are the latest that
    span ``init_seconds``, so a bad start ages out, and at least :data:`MIN_INIT_PAIRS` pairs of them:
    fewer fit any poses exactly).

  The accelerometer bias starts at zero. Gravity's magnitude is then fixed; its direction is refined
  by every window through a tilt ``theta`` (``g = Exp(theta) g0``, the variable ``g0``, a prior of
  ``gravity_tilt_sigma`` about zero set once and carried by the marginalisation prior), as VINS-Fusion
  refines it on its tangent plane.
* **In every window problem** (:meth:`ImuWindow.add_to`): each keyframe with a state gets a
  velocity ``V<index>`` (the IMU's, 3) and a bias ``B<index>`` (6, ``(b_accel, b_gyro)``) variable, marginalised
  with its keyframe (``WindowProblem.keyframe_kinds``); consecutive keyframes the readings cover get
  :func:`factors.imu.imu_factor` over their preintegrated readings; the oldest keyframe with a
  state gets a bias prior and a weak velocity prior until a marginalisation prior carries them.
* **After each solve** (:meth:`ImuWindow.update`) the estimates come back; a new keyframe starts
  from the previous one's bias and the IMU's prediction of its velocity.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

from factors.imu import bias_prior, imu_factor, imu_params, preintegrate, velocity_prior
from gtvo.config.sections.imu import ACCEL_BIAS_SIGMA, GYRO_BIAS_SIGMA, INIT_SECONDS, ImuConfig
from gtvo.core.keys import gravity_tilt_key, imu_bias_key, pose_key, velocity_key
from gtvo.window.config import WindowKeyframe

FloatArray = NDArray[np.float64]


class ImuReadings(Protocol):
    """What the window needs of an IMU log (:class:`gtvo.datasets.imu.ImuMeasurements` is one)."""

    times: FloatArray
    gyro: FloatArray
    accel: FloatArray
    T_cam_imu: FloatArray

    @property
    def noise(self): ...  # gyro_noise_density, accel_noise_density, gyro_random_walk, accel_random_walk

    def covers(self, t0: float, t1: float) -> bool: ...

    def interval(self, t0: float, t1: float) -> tuple[FloatArray, FloatArray, FloatArray]: ...


@dataclass(frozen=True)
class ImuWindowSettings:
    """How the window uses the IMU (the config's ``imu:`` section, :func:`imu_window_settings`).

    Attributes:
        init_seconds: the span of readings and keyframes the initialisation waits for (s).
        gravity: the magnitude of gravity (m/s^2).
        accel_bias_sigma: the accelerometer bias prior's sigma (m/s^2), about zero.
        gyro_bias_sigma: the gyro bias prior's sigma (rad/s), about the initialisation's estimate.
        velocity_sigma: the weak prior on the oldest keyframe's velocity (m/s), about its estimate.
        static_translation: the most the keyframes may move (m) for a static initialisation.
        static_rotation_deg: ... and turn (deg).
        gravity_tilt_sigma: the prior sigma of gravity's tilt from its initial direction (rad).
    """

    init_seconds: float = INIT_SECONDS
    gravity: float = 9.80665
    accel_bias_sigma: float = ACCEL_BIAS_SIGMA
    gyro_bias_sigma: float = GYRO_BIAS_SIGMA
    velocity_sigma: float = 1.0
    static_translation: float = 0.02
    static_rotation_deg: float = 0.5
    gravity_tilt_sigma: float = 0.035



def imu_window_settings(config: ImuConfig) -> ImuWindowSettings:
    """How the window uses the IMU, from the config's ``imu:`` section."""
    return ImuWindowSettings(init_seconds=config.init_seconds, accel_bias_sigma=config.accel_bias_sigma,
                             gyro_bias_sigma=config.gyro_bias_sigma)

#: The moving initialisation is refused (and tried again at the next keyframe) when the gravity its
#: least squares find is off the known magnitude by more than this fraction (VINS-Fusion's check):
#: the keyframes' poses and the readings disagree.
GRAVITY_CHECK = 0.1
#: ... or when the direction it finds is less certain than this (deg, from the residuals).
MAX_INIT_SIGMA_DEG = 2.0
#: The moving initialisation waits for this many consecutive keyframe pairs: with P pairs its least
#: squares has 6 P equations for 3 (P + 1) velocities and gravity, so 2 pairs fit any poses exactly
#: (no residual: a zero sigma, and neither check above can refuse); 3 leave 3 degrees of freedom.
MIN_INIT_PAIRS = 3

#: A re-preintegration is made when a keyframe's bias estimate moved more than this from the one
#: its readings were preintegrated at (accelerometer m/s^2, gyro rad/s; VINS-Fusion's rule).
REPREINTEGRATE = (0.1, 0.01)


@dataclass
class _Seen:
    """A keyframe the IMU owner saw: its time and its latest pose."""

    timestamp: float
    pose: gtsam.Pose3


class ImuWindow:
    """The IMU in the window (module doc).

    Attributes:
        readings: the IMU's log.
        settings: :class:`ImuWindowSettings`.
        gravity0: gravity in the window's world at the initialisation (m/s^2, 3; GTSAM's parameters'),
            None before it.
        tilt: the tilt of gravity's direction since (a rotation vector; :attr:`gravity`).
        gravity_sigma_deg: the initial direction's sigma (deg).
        init_kind: ``"static"`` or ``"moving"`` once initialised, else None.
        velocities, biases: keyframe index -> the IMU's velocity there (m/s, world) and its bias (6).
        factors_added: IMU factors in the window problems built so far (the last one's count).
    """

    def __init__(self, readings: ImuReadings, settings: ImuWindowSettings = ImuWindowSettings()) -> None:
        self.readings = readings
        self.settings = settings
        self.gravity0: FloatArray | None = None
        self.tilt = np.zeros(3)
        self.gravity_sigma_deg: float | None = None
        self.init_kind: str | None = None
        self.init_bias = np.zeros(6)
        self.velocities: dict[int, FloatArray] = {}
        self.biases: dict[int, FloatArray] = {}
        self.factors_added = 0
        self._seen: dict[int, _Seen] = {}
        self._params: gtsam.PreintegrationCombinedParams | None = None
        self._pims: dict[tuple[int, int], tuple[FloatArray, gtsam.PreintegratedCombinedMeasurements]] = {}

    @property
    def initialised(self) -> bool:
        """Whether gravity and the keyframes' states are known."""
        return self.gravity0 is not None

    @property
    def gravity(self) -> FloatArray | None:
        """Gravity in the window's world (m/s^2): the initial one tilted by :attr:`tilt`; None before."""
        return None if self.gravity0 is None else gtsam.Rot3.Expmap(self.tilt).rotate(self.gravity0)

    # ------------------------------------------------------------------------------ preintegration

    def params(self) -> gtsam.PreintegrationCombinedParams:
        """GTSAM's preintegration parameters (after the initialisation: gravity is in them)."""
        if self._params is None:
            n = self.readings.noise
            g = np.zeros(3) if self.gravity0 is None else self.gravity0
            self._params = imu_params(n.gyro_noise_density, n.accel_noise_density, n.gyro_random_walk,
                                      n.accel_random_walk, g)
        return self._params

    def preintegrated(self, t0: float, t1: float, bias: FloatArray) -> gtsam.PreintegratedCombinedMeasurements:
        """The readings from ``t0`` to ``t1`` preintegrated at ``bias``."""
        return preintegrate(self.params(), bias, *self.readings.interval(t0, t1))

    def _pim(self, a: int, b: int, t0: float, t1: float) -> gtsam.PreintegratedCombinedMeasurements:
        """Keyframes ``a``'s to ``b``'s readings, preintegrated at ``a``'s bias (again when it moved far)."""
        bias = self.biases[a]
        cached = self._pims.get((a, b))
        if cached is not None:
            moved = np.abs(cached[0] - bias)
            if moved[:3].max() <= REPREINTEGRATE[0] and moved[3:].max() <= REPREINTEGRATE[1]:
                return cached[1]
        pim = self.preintegrated(t0, t1, bias)
        self._pims[(a, b)] = (bias.copy(), pim)
        return pim

    def predict(self, pose: gtsam.Pose3, velocity: FloatArray, bias: FloatArray, t0: float, t1: float
                ) -> tuple[gtsam.Pose3, FloatArray]:
        """The camera's pose and the IMU's velocity at ``t1`` from the camera's pose and the IMU's
        velocity at ``t0``, by the readings."""
        T_ci = gtsam.Pose3(self.readings.T_cam_imu)
        tilt = gtsam.Pose3(gtsam.Rot3.Expmap(self.tilt), np.zeros(3))  # the parameters' gravity is untilted
        state = self.preintegrated(t0, t1, bias).predict(
            gtsam.NavState(tilt.inverse().compose(pose.compose(T_ci)), tilt.rotation().unrotate(velocity)),
            gtsam.imuBias.ConstantBias(bias[:3], bias[3:]))
        return (tilt.compose(state.pose()).compose(T_ci.inverse()),
                np.asarray(tilt.rotation().rotate(state.velocity()), dtype=float))

    def camera_rotation(self, t0: float, t1: float) -> gtsam.Rot3 | None:
        """The left camera's rotation from ``t0`` to ``t1`` (``R_cam0_cam1``) by the gyro alone, at the
        newest gyro bias estimate (zero before the initialisation): the rotation the gyro measures
        needs neither gravity nor a velocity, so it is known from the first frame on. None when the
        readings do not cover the step."""
        if not (t1 > t0 and self.readings.covers(t0, t1)):
            return None
        bias = self.biases[max(self.biases)] if self.biases else self.init_bias
        R_ci = gtsam.Rot3(self.readings.T_cam_imu[:3, :3])
        return R_ci.compose(self.preintegrated(t0, t1, bias).deltaRij()).compose(R_ci.inverse())

    def predict_at(self, t: float) -> gtsam.Pose3 | None:
        """The camera's pose at ``t`` predicted from the latest keyframe (by time, up to ``t``) with a
        velocity and a bias, at its latest estimate; None before the initialisation or when the
        readings do not cover the step."""
        if not self.initialised:
            return None
        known = [(s.timestamp, i) for i, s in self._seen.items() if i in self.velocities and s.timestamp < t]
        if not known:
            return None
        t0, index = max(known)
        if not self.readings.covers(t0, t):
            return None
        pose, _ = self.predict(self._seen[index].pose, self.velocities[index], self.biases[index], t0, t)
        return pose

    # ------------------------------------------------------------------------------ keyframes

    def keyframe_added(self, keyframes: Sequence[WindowKeyframe]) -> None:
        """The window's keyframes after one joined (the newest last): remember it, initialise when
        the span allows, else give the newest keyframe a state predicted from the previous one's."""
        new = keyframes[-1]
        if new.timestamp is None:
            return
        self._seen[new.index] = _Seen(float(new.timestamp), new.pose)
        if not self.initialised:
            self.try_initialise(keyframes)
            return
        previous = [k for k in keyframes[:-1] if k.index in self.velocities and k.timestamp is not None]
        if not previous:
            return
        p = previous[-1]
        bias = self.biases[p.index].copy()
        velocity = self.velocities[p.index].copy()
        if new.timestamp > p.timestamp and self.readings.covers(p.timestamp, new.timestamp):
            _, velocity = self.predict(p.pose, velocity, bias, p.timestamp, new.timestamp)
        self.velocities[new.index] = velocity
        self.biases[new.index] = bias

    def update(self, variables: gtsam.Values, keyframes: Sequence[WindowKeyframe]) -> None:
        """Take the solved velocities, biases and gravity tilt (``variables``) and the keyframes' solved poses."""
        if variables.exists(gravity_tilt_key()):
            self.tilt = np.asarray(variables.atVector(gravity_tilt_key()), dtype=float).copy()
        for kf in keyframes:
            if kf.index in self._seen:
                self._seen[kf.index].pose = kf.pose
            for key, store in ((velocity_key(kf.index), self.velocities), (imu_bias_key(kf.index), self.biases)):
                if variables.exists(key):
                    store[kf.index] = np.asarray(variables.atVector(key), dtype=float).copy()

    def window_state(self, indices: Sequence[int]) -> dict:
        """What the front end reads of the IMU between window updates (its prediction of the next
        frames, the report): gravity, the initialisation's figures and, for the keyframes
        ``indices`` (the window's), their velocities, biases and poses. A window in a worker
        process hands it back with each update (:meth:`take_window_state`)."""
        keep = set(indices)
        return {"gravity0": None if self.gravity0 is None else self.gravity0.copy(), "tilt": self.tilt.copy(),
                "gravity_sigma_deg": self.gravity_sigma_deg, "init_kind": self.init_kind,
                "init_bias": self.init_bias.copy(), "factors_added": self.factors_added,
                "velocities": {i: v.copy() for i, v in self.velocities.items() if i in keep},
                "biases": {i: b.copy() for i, b in self.biases.items() if i in keep},
                "seen": {i: (s.timestamp, s.pose) for i, s in self._seen.items() if i in keep}}

    def take_window_state(self, state: dict) -> None:
        """Take the worker's :meth:`window_state` (its keyframes' entries join those known)."""
        if state["gravity0"] is None or self.gravity0 is None or not np.array_equal(state["gravity0"], self.gravity0):
            self._params = None  # preintegrated with the new gravity
        self.gravity0, self.tilt = state["gravity0"], state["tilt"]
        self.gravity_sigma_deg, self.init_kind = state["gravity_sigma_deg"], state["init_kind"]
        self.init_bias, self.factors_added = state["init_bias"], state["factors_added"]
        self.velocities.update(state["velocities"])
        self.biases.update(state["biases"])
        self._seen.update({i: _Seen(t, pose) for i, (t, pose) in state["seen"].items()})

    # ------------------------------------------------------------------------------ the problem

    def add_to(self, problem) -> None:
        """Add the IMU's variables and factors to a window problem (module doc). ``problem``: a
        :class:`gtvo.window.problem.WindowProblem` (its ``factors``, ``variables``, ``keyframe_kinds``)."""
        self.factors_added = 0
        if not self.initialised:
            return
        members = [kf for kf in problem.keyframes if kf.index in self.velocities and kf.timestamp is not None]
        if not members:
            return
        for kind in ("V", "B"):
            if kind not in problem.keyframe_kinds:
                problem.keyframe_kinds.append(kind)
        problem.variables.insert(gravity_tilt_key(), self.tilt.copy())
        for kf in members:
            problem.variables.insert(velocity_key(kf.index), self.velocities[kf.index].copy())
            problem.variables.insert(imu_bias_key(kf.index), self.biases[kf.index].copy())
        for a, b in zip(members[:-1], members[1:]):
            if b.timestamp > a.timestamp and self.readings.covers(a.timestamp, b.timestamp):
                pim = self._pim(a.index, b.index, a.timestamp, b.timestamp)
                problem.factors.add(imu_factor(pose_key(a.index), velocity_key(a.index), pose_key(b.index),
                                               velocity_key(b.index), imu_bias_key(a.index), imu_bias_key(b.index),
                                               pim, self.readings.T_cam_imu, gravity_tilt_key()))
                self.factors_added += 1
        first = members[0]
        marginal = problem.marginal
        if marginal is None or gravity_tilt_key() not in marginal.keys:  # set once, then carried
            problem.factors.add(gtsam.PriorFactorVector(gravity_tilt_key(), np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(
                3, self.settings.gravity_tilt_sigma)))
        if marginal is None or imu_bias_key(first.index) not in marginal.keys:
            s = self.settings
            problem.factors.add(bias_prior(imu_bias_key(first.index), self.init_bias, s.accel_bias_sigma,
                                           s.gyro_bias_sigma))
            problem.factors.add(velocity_prior(velocity_key(first.index), self.velocities[first.index],
                                               s.velocity_sigma))

    # ------------------------------------------------------------------------------ initialisation

    def try_initialise(self, keyframes: Sequence[WindowKeyframe], finishing: bool = False) -> bool:
        """Initialise (module doc) when the keyframes seen span ``init_seconds`` of readings (or,
        ``finishing`` the run, when the readings do: a static log makes no second keyframe); then
        every keyframe of ``keyframes`` gets a state. Returns whether it is initialised."""
        if self.initialised:
            return True
        seen = sorted(self._seen.items(), key=lambda kv: kv[1].timestamp)
        if not seen:
            return False
        t0 = seen[0][1].timestamp
        t_end = max(seen[-1][1].timestamp, t0)
        if not self.readings.covers(t0, t0 + self.settings.init_seconds):
            return False
        if t_end - t0 < self.settings.init_seconds and not finishing:
            return False
        static = self._static(seen)
        if static:
            ok = self._initialise_static(seen, t0)
        else:  # the latest keyframes that span init_seconds: a bad start ages out of a refused one
            last = max(k for k in range(len(seen)) if t_end - seen[k][1].timestamp >= self.settings.init_seconds)
            recent = seen[last:]
            ok = len(recent) >= MIN_INIT_PAIRS + 1 and self._initialise_moving(recent)
        if not ok:
            return False
        self._params = None  # gravity is known now
        self._pims.clear()
        for kf in keyframes:
            if kf.index not in self.velocities and kf.timestamp is not None:
                self.velocities[kf.index] = np.zeros(3) if static else self._velocity_at(seen, kf.index)
                self.biases[kf.index] = self.init_bias.copy()
        return True

    def _static(self, seen: list[tuple[int, _Seen]]) -> bool:
        s = self.settings
        first = seen[0][1].pose
        for _, k in seen[1:]:
            rel = first.between(k.pose)
            if (np.linalg.norm(rel.translation()) > s.static_translation
                    or np.degrees(np.linalg.norm(gtsam.Rot3.Logmap(rel.rotation())))) > s.static_rotation_deg:
                return False
        return True

    def _initialise_static(self, seen: list[tuple[int, _Seen]], t0: float) -> bool:
        r = self.readings
        t1 = t0 + self.settings.init_seconds
        m = (r.times >= t0) & (r.times <= t1)
        if np.count_nonzero(m) < 10:
            return False
        f = r.accel[m]
        R_world_imu = seen[0][1].pose.rotation().matrix() @ r.T_cam_imu[:3, :3]
        g = -R_world_imu @ f.mean(axis=0)
        norm = float(np.linalg.norm(g))
        self.gravity0 = g / norm * self.settings.gravity
        # the direction's sigma: the accelerometer's white noise over the averaged readings
        n = int(np.count_nonzero(m))
        sigma_f = float(np.std(f - f.mean(axis=0), axis=0).mean()) / np.sqrt(n)
        self.gravity_sigma_deg = float(np.degrees(sigma_f / norm))
        self.init_bias = np.r_[np.zeros(3), r.gyro[m].mean(axis=0)]
        self.init_kind = "static"
        for index, _ in seen:
            self.velocities.setdefault(index, np.zeros(3))
            self.biases.setdefault(index, self.init_bias.copy())
        return True

    def _initialise_moving(self, seen: list[tuple[int, _Seen]]) -> bool:
        r = self.readings
        T_ci = gtsam.Pose3(r.T_cam_imu)
        imu_poses = [k.pose.compose(T_ci) for _, k in seen]
        times = [k.timestamp for _, k in seen]
        pairs = [(i, i + 1) for i in range(len(seen) - 1) if times[i + 1] > times[i]
                 and r.covers(times[i], times[i + 1])]
        if len(pairs) < MIN_INIT_PAIRS:  # fewer: no residual, no sigma, no check (module doc)
            return False
        zero = np.zeros(6)
        # 1. the gyro bias from the relative rotations (GTSAM's params with zero gravity: rotations only)
        self._params, self.gravity0 = None, None
        pims = {p: self.preintegrated(times[p[0]], times[p[1]], zero) for p in pairs}
        A, b = [], []
        h = 1e-4  # the preintegrated rotation's derivative in the gyro bias, by differences
        for (i, j), pim in pims.items():
            dR = pim.deltaRij()
            R_ij = imu_poses[i].rotation().between(imu_poses[j].rotation())
            b.append(gtsam.Rot3.Logmap(dR.between(R_ij)))
            J = np.empty((3, 3))
            for axis in range(3):
                step = np.zeros(6)
                step[3 + axis] = h
                moved = self.preintegrated(times[i], times[j], step).deltaRij()
                J[:, axis] = gtsam.Rot3.Logmap(dR.between(moved)) / h
            A.append(J)
        bg = np.linalg.lstsq(np.vstack(A), np.concatenate(b), rcond=None)[0]
        bias = np.r_[np.zeros(3), bg]
        pims = {p: self.preintegrated(times[p[0]], times[p[1]], bias) for p in pairs}
        # 2. gravity and the IMU's velocities (linear least squares), gravity rescaled, velocities again
        g, v, sigma_deg = _gravity_and_velocities(pairs, pims, imu_poses, times, None)
        if (g is None or abs(np.linalg.norm(g) - self.settings.gravity) > GRAVITY_CHECK * self.settings.gravity
                or sigma_deg is None or sigma_deg > MAX_INIT_SIGMA_DEG):
            return False  # the keyframes and the readings disagree (a bad visual start): try again later
        g = g / np.linalg.norm(g) * self.settings.gravity
        _, v, _ = _gravity_and_velocities(pairs, pims, imu_poses, times, g)
        self.gravity0, self.gravity_sigma_deg = g, sigma_deg
        self.init_bias = bias
        self.init_kind = "moving"
        for k, (index, kseen) in enumerate(seen):
            self.velocities[index] = v[k].copy()
            self.biases[index] = bias.copy()
        return True

    def _velocity_at(self, seen: list[tuple[int, _Seen]], index: int) -> FloatArray:
        """A keyframe's velocity after the initialisation: its own, or the nearest seen one's."""
        return self.velocities.get(index, self.velocities[seen[-1][0]]).copy()

    # ------------------------------------------------------------------------------ report

    def report(self, bias_covariance: FloatArray | None = None, tilt_covariance: FloatArray | None = None) -> dict:
        """The IMU's figures for ``report.json``: gravity in the window's world and its direction's
        sigma (the tilt's marginal covariance across gravity, else the initialisation's), the latest
        keyframe's biases and their sigmas."""
        latest = max(self.biases) if self.biases else None
        bias = self.biases[latest] if latest is not None else None
        sig = None if bias_covariance is None else np.sqrt(np.clip(np.diag(bias_covariance), 0, None))
        g = self.gravity
        sigma_deg = self.gravity_sigma_deg
        if g is not None and tilt_covariance is not None and self.factors_added > 0:  # else the prior's
            u = g / np.linalg.norm(g)
            across = np.eye(3) - np.outer(u, u)
            sigma_deg = float(np.degrees(np.sqrt(max(np.trace(across @ tilt_covariance @ across), 0.0))))
        return {
            "initialised": self.init_kind,
            "gravity_world": None if g is None else [float(x) for x in g],
            "gravity_sigma_deg": sigma_deg,
            "gravity_tilt_deg": float(np.degrees(np.linalg.norm(self.tilt))),
            "gyro_bias": None if bias is None else [float(x) for x in bias[3:]],
            "gyro_bias_sigma": None if sig is None else [float(x) for x in sig[3:]],
            "accel_bias": None if bias is None else [float(x) for x in bias[:3]],
            "accel_bias_sigma": None if sig is None else [float(x) for x in sig[:3]],
            "factors_last_window": self.factors_added,
        }


def _gravity_and_velocities(pairs, pims, imu_poses, times, gravity: FloatArray | None
                            ) -> tuple[FloatArray | None, FloatArray, float | None]:
    """Least squares for the IMU velocities (one per pose, 3) and (``gravity`` None) gravity from
    ``v_j - v_i - g dt = R_i dv`` and ``v_i dt + g dt^2 / 2 = p_j - p_i - R_i dp`` per pair; with
    the direction's sigma (deg) from the residuals."""
    n = len(imu_poses)
    cols = 3 * n + (3 if gravity is None else 0)
    rows, rhs = [], []
    for (i, j), pim in zip(pairs, (pims[p] for p in pairs)):
        dt = times[j] - times[i]
        R_i = imu_poses[i].rotation().matrix()
        dv = R_i @ np.asarray(pim.deltaVij())
        dp = R_i @ np.asarray(pim.deltaPij())
        p_i, p_j = imu_poses[i].translation(), imu_poses[j].translation()
        for axis in range(3):
            row = np.zeros(cols)
            row[3 * j + axis], row[3 * i + axis] = 1.0, -1.0
            r = dv[axis]
            if gravity is None:
                row[3 * n + axis] = -dt
            else:
                r += gravity[axis] * dt
            rows.append(row)
            rhs.append(r)
            row = np.zeros(cols)
            row[3 * i + axis] = dt
            r = p_j[axis] - p_i[axis] - dp[axis]
            if gravity is None:
                row[3 * n + axis] = 0.5 * dt * dt
            else:
                r -= 0.5 * gravity[axis] * dt * dt
            rows.append(row)
            rhs.append(r)
    A, y = np.asarray(rows), np.asarray(rhs)
    x, *_ = np.linalg.lstsq(A, y, rcond=None)
    v = x[:3 * n].reshape(n, 3)
    if gravity is not None:
        return gravity, v, None
    g = x[3 * n:]
    dof = max(A.shape[0] - A.shape[1], 1)
    s2 = float(np.sum((A @ x - y) ** 2)) / dof
    cov = s2 * np.linalg.pinv(A.T @ A)[3 * n:, 3 * n:]
    u = g / np.linalg.norm(g)
    P = np.eye(3) - np.outer(u, u)
    sigma = float(np.degrees(np.sqrt(max(np.trace(P @ cov @ P), 0.0)) / np.linalg.norm(g)))
    return g, v, sigma
