r"""The rig's sensors: what a noise-free platen travel and force look like once logged.

A :class:`SensorModel` turns the true history of one loading cycle (platen travel and platen
force as functions of time) into the samples the rig's logger writes. It models the two
sensors of the rig in the thesis (du Plessis 2016, Sect. 6.1):

* a Burster 8523 load cell of 20 N capacity, run to about 10 N: a tare (zero) offset of up to
  a few tens of mN, coloured noise of a few mN (a first-order autoregressive process, AR(1),
  whose stationary standard deviation and lag-one correlation are configured), and the
  quantisation of a 16-bit converter over +-20 N (0.61 mN per count), saturating at the range;
* a platen encoder: white noise of about 1 um and a resolution of 1 um.

The logger samples at 50-200 Hz depending on the platen speed (about one sample per 3-30 um of
travel), with timestamp jitter, occasional repeated timestamps (a stale clock value written
with a fresh sample), and short gaps (runs of samples lost to a buffer overrun).

Everything is drawn from a :class:`numpy.random.Generator` passed in by the caller, so a seed
reproduces every sample. Units: s, mm, N throughout; the compression-positive frame (sign
conventions and file units are the writer's business, :mod:`experiments.rigfile`).

The AR(1) force noise is

.. math::

    e_i = \phi\, e_{i-1} + \sigma \sqrt{1-\phi^2}\, w_i, \qquad w_i \sim N(0, 1),
    \qquad e_0 \sim N(0, \sigma^2),

stationary with standard deviation :math:`\sigma` and lag-one autocorrelation :math:`\phi`.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.signal import lfilter

__all__ = ["SensorModel", "SampledCycle", "ar1_noise", "quantise"]


def ar1_noise(n: int, std: float, phi: float, rng: np.random.Generator) -> np.ndarray:
    """Stationary AR(1) noise.

    Parameters
    ----------
    n : int
        Number of samples.
    std : float
        Stationary standard deviation :math:`\\sigma` (same unit as the output).
    phi : float
        Lag-one autocorrelation, ``-1 < phi < 1`` (0 gives white noise).
    rng : numpy.random.Generator

    Returns
    -------
    ndarray, shape (n,)
    """
    if not -1.0 < phi < 1.0:
        raise ValueError(f"AR(1) coefficient phi={phi} must lie in (-1, 1)")
    if std < 0:
        raise ValueError(f"noise standard deviation {std} must be non-negative")
    w = rng.standard_normal(n)
    if n == 0:
        return w
    innov = std * np.sqrt(1.0 - phi * phi)
    # e_0 = std w_0 (stationary start), then the recursion as a first-order IIR filter
    head = std * w[0]
    tail = lfilter([innov], [1.0, -phi], w[1:], zi=[phi * head])[0]
    return np.concatenate([[head], tail])


def quantise(x, step: float, lo: float = -np.inf, hi: float = np.inf) -> np.ndarray:
    """Round to the nearest multiple of ``step`` and clip to ``[lo, hi]`` (saturation)."""
    if not step > 0:
        raise ValueError(f"quantisation step {step} must be positive")
    return np.clip(np.round(np.asarray(x, dtype=float) / step) * step, lo, hi)


@dataclasses.dataclass(frozen=True)
class SampledCycle:
    """The logged samples of one cycle, compression-positive frame, before any file formatting.

    Attributes
    ----------
    time_s : ndarray, shape (n,)
        Logged timestamps (s): jittered, rounded to the logger clock, occasionally repeated.
    displacement_mm : ndarray, shape (n,)
        Logged platen travel (mm), noisy and quantised.
    force_N : ndarray, shape (n,)
        Logged load-cell force (N): true force plus tare plus noise, quantised.
    true_time_s, true_displacement_mm, true_force_N : ndarray, shape (n,)
        The noise-free values at the true sampling instants (for tests and the truth file).
    info : dict
        What was drawn: tare, number of repeated timestamps, gaps (start time and length).
    """

    time_s: np.ndarray
    displacement_mm: np.ndarray
    force_N: np.ndarray
    true_time_s: np.ndarray
    true_displacement_mm: np.ndarray
    true_force_N: np.ndarray
    info: dict


@dataclasses.dataclass(frozen=True)
class SensorModel:
    """Load cell, encoder and logger of the rig.

    Parameters
    ----------
    force_noise_N : float
        Stationary standard deviation of the load-cell noise (N).
    force_ar1 : float
        Lag-one autocorrelation of the load-cell noise (dimensionless, 0 = white).
    force_range_N : float
        Converter range +- (N); the signal saturates there.
    force_bits : int
        Converter resolution (bits over the full range, 2 x ``force_range_N``).
    tare_max_N : float
        The load-cell zero offset is drawn uniformly in +-``tare_max_N`` (N).
    displacement_noise_mm : float
        Standard deviation of the encoder noise (mm).
    displacement_resolution_mm : float
        Encoder resolution (mm).
    clock_resolution_s : float
        Resolution of the logged timestamps (s).
    jitter_fraction : float
        Standard deviation of the sampling-instant jitter over the sampling period; the jitter
        is clipped to +-0.4 periods so that true instants stay in order.
    repeat_probability : float
        Probability per sample that the logger writes the previous timestamp again.
    gaps_per_file : tuple of int
        Inclusive range of the number of gaps per file.
    gap_samples : tuple of int
        Inclusive range of the number of samples lost in one gap.
    """

    force_noise_N: float = 0.003
    force_ar1: float = 0.6
    force_range_N: float = 20.0
    force_bits: int = 16
    tare_max_N: float = 0.03
    displacement_noise_mm: float = 0.001
    displacement_resolution_mm: float = 0.001
    clock_resolution_s: float = 0.001
    jitter_fraction: float = 0.05
    repeat_probability: float = 0.003
    gaps_per_file: tuple[int, int] = (0, 2)
    gap_samples: tuple[int, int] = (3, 15)

    def __post_init__(self):
        for name in ("force_noise_N", "tare_max_N", "displacement_noise_mm",
                     "jitter_fraction", "repeat_probability"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"SensorModel.{name}={value} must be a non-negative number")
        for name in ("force_range_N", "displacement_resolution_mm", "clock_resolution_s"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"SensorModel.{name}={value} must be a positive number")
        if not -1.0 < self.force_ar1 < 1.0:
            raise ValueError(f"SensorModel.force_ar1={self.force_ar1} must lie in (-1, 1)")
        if not 8 <= self.force_bits <= 32:
            raise ValueError(f"SensorModel.force_bits={self.force_bits} must lie in [8, 32]")
        if self.repeat_probability >= 0.5:
            raise ValueError(f"SensorModel.repeat_probability={self.repeat_probability} "
                             "must be below 0.5")
        for name in ("gaps_per_file", "gap_samples"):
            lo, hi = getattr(self, name)
            if not 0 <= lo <= hi:
                raise ValueError(f"SensorModel.{name}={(lo, hi)} must be an ordered range "
                                 "of non-negative integers")

    @property
    def force_step_N(self) -> float:
        """Load-cell quantisation step (N): the full range over ``2**force_bits`` counts."""
        return 2.0 * self.force_range_N / 2**self.force_bits

    @staticmethod
    def sample_rate_hz(rate_mm_per_s: float) -> float:
        """Logger sampling frequency (Hz) for a platen speed (mm/s).

        50 Hz below 0.5 mm/s, 100 Hz up to 3 mm/s, 200 Hz above: between 3 and 30 um of
        travel per sample at the rig's speeds.
        """
        if rate_mm_per_s < 0.5:
            return 50.0
        if rate_mm_per_s <= 3.0:
            return 100.0
        return 200.0

    def to_dict(self) -> dict:
        """The configuration as plain JSON-ready values."""
        out = dataclasses.asdict(self)
        out["force_step_N"] = self.force_step_N
        out["sample_rate_rule_hz"] = {"below_0.5_mm_per_s": 50.0, "0.5_to_3_mm_per_s": 100.0,
                                      "above_3_mm_per_s": 200.0}
        return out

    # ------------------------------------------------------------------ sampling
    def sample_instants(self, duration_s: float, rate_hz: float,
                        rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, dict]:
        """True sampling instants and the timestamps the logger writes for them.

        Parameters
        ----------
        duration_s : float
            Length of the record (s).
        rate_hz : float
            Nominal sampling frequency (Hz).
        rng : numpy.random.Generator

        Returns
        -------
        true_s : ndarray, shape (n,)
            Increasing true sampling instants (s), first at 0.
        logged_s : ndarray, shape (n,)
            Timestamps written (s): rounded to the clock, some repeated from the previous row.
        info : dict
            ``n_repeated`` and ``gaps`` (list of ``{"start_s", "n_samples"}``).
        """
        period = 1.0 / rate_hz
        n_nominal = int(np.floor(duration_s * rate_hz)) + 1
        jitter = np.clip(self.jitter_fraction * rng.standard_normal(n_nominal), -0.4, 0.4)
        jitter[0] = 0.0
        true_s = (np.arange(n_nominal) + jitter) * period
        keep = np.ones(n_nominal, dtype=bool)
        gaps = []
        n_gaps = int(rng.integers(self.gaps_per_file[0], self.gaps_per_file[1] + 1))
        for _ in range(n_gaps):
            length = int(rng.integers(self.gap_samples[0], self.gap_samples[1] + 1))
            if n_nominal < 4 * length + 10:
                continue
            start = int(rng.integers(5, n_nominal - length - 5))
            keep[start:start + length] = False
            gaps.append({"start_s": float(true_s[start]), "n_samples": length})
        true_s = true_s[keep]
        logged_s = np.round(true_s / self.clock_resolution_s) * self.clock_resolution_s
        repeat = rng.random(len(logged_s)) < self.repeat_probability
        repeat[0] = False
        idx = np.arange(len(logged_s))
        # a repeated timestamp copies the last fresh one before it (runs of repeats allowed)
        fresh = np.where(repeat, 0, idx)
        np.maximum.accumulate(fresh, out=fresh)
        logged_s = logged_s[fresh]
        info = {"n_repeated": int(repeat.sum()), "gaps": gaps,
                "n_samples": int(len(true_s)), "rate_hz": float(rate_hz)}
        return true_s, logged_s, info

    def record(self, true_s: np.ndarray, logged_s: np.ndarray, travel_mm: np.ndarray,
               force_N: np.ndarray, rng: np.random.Generator, info: dict | None = None,
               tare_N: float | None = None) -> SampledCycle:
        """Add the sensors' errors to the true travel and force at the sampling instants.

        Parameters
        ----------
        true_s, logged_s : ndarray, shape (n,)
            From :meth:`sample_instants`.
        travel_mm, force_N : ndarray, shape (n,)
            True platen travel (mm) and platen force (N, compression positive) at ``true_s``.
        rng : numpy.random.Generator
        info : dict, optional
            Sampling information to carry into the result.
        tare_N : float, optional
            Load-cell zero offset (N); drawn in +-``tare_max_N`` if omitted.

        Returns
        -------
        SampledCycle
        """
        n = len(true_s)
        if not (len(logged_s) == len(travel_mm) == len(force_N) == n):
            raise ValueError("time, travel and force arrays must have the same length, got "
                             f"{n}, {len(travel_mm)}, {len(force_N)} and {len(logged_s)}")
        if tare_N is None:
            tare_N = float(rng.uniform(-self.tare_max_N, self.tare_max_N))
        noise = ar1_noise(n, self.force_noise_N, self.force_ar1, rng)
        force = quantise(force_N + tare_N + noise, self.force_step_N,
                         -self.force_range_N, self.force_range_N - self.force_step_N)
        d_noise = self.displacement_noise_mm * rng.standard_normal(n)
        travel = quantise(travel_mm + d_noise, self.displacement_resolution_mm)
        out_info = dict(info or {})
        out_info["tare_N"] = float(tare_N)
        out_info["saturated_samples"] = int(np.sum(np.abs(force_N + tare_N + noise)
                                                   >= self.force_range_N))
        return SampledCycle(time_s=np.asarray(logged_s, float), displacement_mm=travel,
                            force_N=force, true_time_s=np.asarray(true_s, float),
                            true_displacement_mm=np.asarray(travel_mm, float),
                            true_force_N=np.asarray(force_N, float), info=out_info)
