"""Gradient-boosted trees read from a shipped model's JSON and evaluated by
our own code (no scikit-learn at runtime): the ROI scoring model
(``roi_model.json``) and the fibroglandular pixel model
(``tissue_model.json``) share it."""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["TreeEnsemble", "exported_trees"]

_NODE_ARRAYS = ("feature", "threshold", "left", "right", "leaf", "value")


class TreeEnsemble:
    """Boosted trees: the log-odds of a sample is ``baseline`` plus, for every
    tree, the value of the leaf it reaches (it goes left where its descriptor
    is at most the node's threshold).

    Parameters
    ----------
    baseline : float
        The log-odds before any tree.
    trees : list of dict
        Per tree the node arrays ``feature``, ``threshold``, ``left``,
        ``right``, ``leaf`` (0/1) and ``value`` (scikit-learn's
        ``HistGradientBoostingClassifier`` predictor nodes); node 0 is the
        root.
    """

    def __init__(self, baseline, trees):
        self.baseline = float(baseline)
        sizes = [len(t["feature"]) for t in trees]
        # every tree's nodes one after another; child indices shifted to match
        self.roots = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
        shift = np.repeat(self.roots, sizes)
        cat = {k: np.concatenate([np.asarray(t[k]) for t in trees]) if trees else np.zeros(0)
               for k in _NODE_ARRAYS}
        self.feature = cat["feature"].astype(np.int64)
        self.threshold = cat["threshold"].astype(np.float64)
        self.left = cat["left"].astype(np.int64) + shift
        self.right = cat["right"].astype(np.int64) + shift
        self.leaf = cat["leaf"].astype(bool)
        self.value = cat["value"].astype(np.float64)
        self.n_features = int(self.feature[~self.leaf].max()) + 1 if (~self.leaf).any() else 0

    def log_odds(self, X):
        """The log-odds (n,) of the rows of ``X`` (n, at least ``n_features``)."""
        X = np.ascontiguousarray(X, dtype=np.float64)
        if X.ndim != 2 or X.shape[1] < self.n_features:
            raise ValueError(f"the trees need rows of at least {self.n_features} descriptors; "
                             f"got shape {X.shape}.")
        return _sum_of_leaves(X, self.roots, self.feature, self.threshold, self.left,
                              self.right, self.leaf, self.value, self.baseline)


def exported_trees(classifier):
    """(baseline, trees) of a fitted binary scikit-learn
    ``HistGradientBoostingClassifier``, as :class:`TreeEnsemble` and the
    model JSON files read them (used by the benchmarks that fit them)."""
    trees = []
    for (predictor,) in classifier._predictors:
        nodes = predictor.nodes
        trees.append({"feature": nodes["feature_idx"].tolist(),
                      "threshold": nodes["num_threshold"].tolist(),
                      "left": nodes["left"].tolist(), "right": nodes["right"].tolist(),
                      "leaf": nodes["is_leaf"].astype(int).tolist(),
                      "value": nodes["value"].tolist()})
    return float(np.ravel(classifier._baseline_prediction)[0]), trees


@njit(cache=True, nogil=True)
def _sum_of_leaves(X, roots, feature, threshold, left, right, leaf, value, baseline):
    out = np.empty(X.shape[0])
    for i in range(X.shape[0]):
        total = baseline
        for root in roots:  # tree by tree, so the sum's order is the trees'
            node = root
            while not leaf[node]:
                node = left[node] if X[i, feature[node]] <= threshold[node] else right[node]
            total += value[node]
        out[i] = total
    return out
