"""Classification against the truth labels of a simulated scan.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tlsvox.classify._classes import TRUTH_CLASS, PointClass
from tlsvox.errors import InputError


@dataclass
class Score:
    """Labels against truth.

    Attributes
    ----------
    classes : list of PointClass
        Row/column order of the matrix.
    confusion : (C, C) int
        ``confusion[i, j]``: echoes of true class ``classes[i]`` labelled ``classes[j]``.
    precision, recall : dict name -> float (NaN where undefined)
    """

    classes: list
    confusion: np.ndarray
    precision: dict
    recall: dict

    def table(self) -> str:
        """Markdown table of the confusion matrix with precision and recall."""
        names = [c.name.lower() for c in self.classes]
        head = "| truth \\ label | " + " | ".join(names) + " | recall |"
        lines = [head, "|" + "---|" * (len(names) + 2)]
        for i, n in enumerate(names):
            row = " | ".join(str(int(v)) for v in self.confusion[i])
            lines.append(f"| {n} | {row} | {self.recall[n]:.3f} |")
        lines.append("| precision | " + " | ".join(f"{self.precision[n]:.3f}" for n in names) + " | |")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return {"classes": [c.name.lower() for c in self.classes], "confusion": self.confusion.tolist(),
                "precision": self.precision, "recall": self.recall}


def score(labels, truth_material) -> Score:
    """Confusion matrix, precision and recall of labels against truth materials.

    Parameters
    ----------
    labels : (N,) PointClass values
    truth_material : (N,) :class:`voxlidar.materials.Material` ids

    Returns
    -------
    Score
    """
    labels = np.asarray(labels).reshape(-1)
    truth = np.asarray(truth_material).reshape(-1)
    if labels.shape != truth.shape:
        raise InputError(f"labels {labels.shape} and truth_material {truth.shape} must have the same length")
    classes = list(PointClass)
    index = {int(c): i for i, c in enumerate(classes)}
    lut = np.full(256, index[PointClass.NOISE], np.int64)
    for mat, cls in TRUTH_CLASS.items():
        lut[int(mat)] = index[int(cls)]
    t_idx = lut[truth.astype(np.int64)]
    l_idx = np.array([index.get(int(v), -1) for v in np.unique(labels)])
    if np.any(l_idx < 0):
        raise InputError(f"labels hold values that are not PointClass codes: {np.unique(labels).tolist()}")
    llut = np.zeros(256, np.int64)
    for c in classes:
        llut[int(c)] = index[int(c)]
    p_idx = llut[labels.astype(np.int64)]
    C = len(classes)
    conf = np.bincount(t_idx * C + p_idx, minlength=C * C).reshape(C, C)
    prec, rec = {}, {}
    for i, c in enumerate(classes):
        col, row = conf[:, i].sum(), conf[i].sum()
        prec[c.name.lower()] = float(conf[i, i] / col) if col else float("nan")
        rec[c.name.lower()] = float(conf[i, i] / row) if row else float("nan")
    return Score(classes, conf, prec, rec)
