"""Echoes of many waveforms as one flat table (:class:`EchoTable`), and its I/O."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clsim.errors import InputError
from clsim.waveforms.decompose._model import Components, EchoColumns


@dataclass(kw_only=True)
class EchoTable(EchoColumns):
    """Gaussian echoes of N waveforms: one row per echo, sorted by waveform then time.

    Attributes
    ----------
    amplitude, location_ns, sigma_ns, amplitude_se, location_se_ns, sigma_se_ns : (E,) float64
        As in :class:`Components` (``COLUMNS``).
    waveform : (E,) int64
        Index of the waveform each echo belongs to.
    baseline, baseline_se, noise_sigma, rss : (N,) float64
        Per waveform.

    ``table[i]`` is waveform ``i``'s :class:`Components` (:meth:`components`: all of
    them); ``len(table)`` is N. Build it with keywords (the columns come first).
    """

    waveform: np.ndarray
    baseline: np.ndarray
    baseline_se: np.ndarray
    noise_sigma: np.ndarray
    rss: np.ndarray

    def __len__(self) -> int:
        return int(self.baseline.size)

    @property
    def n_echoes(self) -> int:
        """E, echoes in all waveforms."""
        return int(self.waveform.size)

    @property
    def counts(self) -> np.ndarray:
        """(N,) int64, echoes per waveform."""
        return np.bincount(self.waveform, minlength=len(self))

    def __getitem__(self, i: int) -> Components:
        if not -len(self) <= int(i) < len(self):
            raise IndexError(f"waveform index {i} out of range for {len(self)} waveforms")
        i = int(i) % len(self)
        lo, hi = np.searchsorted(self.waveform, [i, i + 1])
        return Components(*(getattr(self, c)[lo:hi].copy() for c in self.COLUMNS),
                          baseline=float(self.baseline[i]),
                          baseline_se=float(self.baseline_se[i]),
                          noise_sigma=float(self.noise_sigma[i]), rss=float(self.rss[i]))

    def components(self) -> list:
        """Every waveform's :class:`Components`, in order: ``[table[i] for i in
        range(len(table))]`` with the columns split once (faster for many)."""
        cuts = np.searchsorted(self.waveform, np.arange(1, len(self)))
        cols = [np.split(getattr(self, c), cuts) for c in self.COLUMNS]
        per = [self.baseline.tolist(), self.baseline_se.tolist(), self.noise_sigma.tolist(),
               self.rss.tolist()]
        return [Components(*(c[i].copy() for c in cols), baseline=per[0][i],
                           baseline_se=per[1][i], noise_sigma=per[2][i], rss=per[3][i])
                for i in range(len(self))]

    def to_records(self) -> np.ndarray:
        """One structured row per echo: ``waveform``, the columns, and ``baseline``."""
        dtype = [("waveform", "i8")] + [(c, "f8") for c in self.COLUMNS] + [("baseline", "f8")]
        out = np.empty(self.n_echoes, dtype=dtype)
        out["waveform"] = self.waveform
        for c in self.COLUMNS:
            out[c] = getattr(self, c)
        out["baseline"] = self.baseline[self.waveform]
        return out

    def save_csv(self, path) -> None:
        """Write :meth:`to_records` as CSV (header line, one echo per line)."""
        path = Path(path)
        if path.suffix.lower() != ".csv":
            raise InputError(f"path must end in .csv; got {str(path)!r}")
        rec = self.to_records()
        fmt = ["%d"] + ["%.9g"] * (len(rec.dtype.names) - 1)
        np.savetxt(path, np.column_stack([rec[c] for c in rec.dtype.names]), delimiter=",",
                   header=",".join(rec.dtype.names), comments="", fmt=fmt)

    @classmethod
    def from_components(cls, comps) -> EchoTable:
        """Stack a sequence of :class:`Components` (one per waveform)."""
        comps = list(comps)
        counts = np.array([len(c) for c in comps], dtype=np.int64)
        cols = {c: (np.concatenate([getattr(x, c) for x in comps]) if comps else np.zeros(0))
                for c in cls.COLUMNS}
        per = {k: np.array([getattr(x, k) for x in comps], dtype=float)
               for k in ("baseline", "baseline_se", "noise_sigma", "rss")}
        return cls(waveform=np.repeat(np.arange(len(comps)), counts), **cols, **per)
