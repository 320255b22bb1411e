"""Colour model of the shirt (section 5.1 of seed 001) and white balance.

Each of the shirt's K colours is a Gaussian ``N(mu_k, Sigma_k)`` in *linear* RGB
(``0..1``), trained ahead of time on white-balanced frames whose patches are labelled
(scribbles, or the bench's id maps).  At run time a 3x3 white-balance matrix ``W``
maps a camera's linear colours to the model's reference illumination, ``W I ~ mu``;
it is solved by least squares from colour means under labelled pixels (a user's
scribbles on the first frame, later the id map of the tracked pose), and a list of
:class:`ReferenceIlluminations` keeps the distinct ``W`` seen so far.

Why linear RGB: webcams deliver gamma-encoded (sRGB) values, and a change of
illuminant multiplies *linear* channel values; a 3x3 matrix is the right model only
after undoing the gamma (one 256-entry lookup table, :data:`SRGB_TO_LINEAR`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numba
import numpy as np
from scipy.cluster.vq import kmeans2

from mocap.errors import MocapInputError
from mocap.npz_files import read_npz
from mocap.srgb import SRGB_TO_LINEAR as _SRGB_TO_LINEAR_F64

__all__ = [
    "SRGB_TO_LINEAR",
    "to_linear",
    "linear_lookup",
    "ColourModel",
    "train_colour_model",
    "labelled_colour_means",
    "solve_white_balance",
    "initial_white_balance",
    "ReferenceIlluminations",
    "NOT_SHIRT",
    "train_other_colours",
]

NOT_SHIRT = -2
"""Label of pixels the user marks as *not shirt* (trousers, skin, background); -1 is unlabelled."""


SRGB_TO_LINEAR = _SRGB_TO_LINEAR_F64.astype(np.float32)
"""(256,) float32: 8-bit sRGB code -> linear value in 0..1 (IEC 61966-2-1)."""
SRGB_TO_LINEAR.setflags(write=False)


def to_linear(image: np.ndarray) -> np.ndarray:
    """uint8 sRGB ``(..., 3)`` -> float32 linear RGB in ``0..1`` (same shape)."""
    img = np.asarray(image)
    if img.dtype != np.uint8:
        raise MocapInputError(f"to_linear: expected uint8 sRGB pixels, got dtype {img.dtype}")
    return linear_lookup(img)


def linear_lookup(codes: np.ndarray) -> np.ndarray:
    """``SRGB_TO_LINEAR[codes]``; for uint8 codes in one compiled pass (numpy's fancy indexing first converts
    every code to a 64-bit index: 0.24 ms a 144 x 144 crop, two or three a frame)."""
    c = np.asarray(codes)
    if c.dtype != np.uint8:
        return SRGB_TO_LINEAR[c]
    return _lookup_u8(np.ascontiguousarray(c).reshape(-1), SRGB_TO_LINEAR).reshape(c.shape)


@numba.njit(cache=True, nogil=True)
def _lookup_u8(codes, table):  # pragma: no cover
    out = np.empty(codes.shape[0], table.dtype)
    for i in range(codes.shape[0]):
        out[i] = table[codes[i]]
    return out


@dataclass(frozen=True, eq=False)
class ColourModel:
    """One Gaussian per shirt colour, in linear RGB of the reference illumination.

    Attributes
    ----------
    means : (K, 3) float
    covariances : (K, 3, 3) float
    names : tuple[str, ...]
    whiten : (K, 3, 3) float
        ``L_k^-1`` with ``Sigma_k = L_k L_k^T``: ``|L_k^-1 (x - mu_k)|`` is the Mahalanobis distance.
    """

    means: np.ndarray
    covariances: np.ndarray
    names: tuple[str, ...]

    def __post_init__(self) -> None:
        K = len(self.names)
        mu = np.asarray(self.means, float)
        cov = np.asarray(self.covariances, float)
        if mu.shape != (K, 3) or cov.shape != (K, 3, 3):
            raise MocapInputError(f"ColourModel: means must be ({K}, 3) and covariances ({K}, 3, 3), got {mu.shape} and {cov.shape}")
        try:
            L = np.linalg.cholesky(cov)
        except np.linalg.LinAlgError:
            raise MocapInputError("ColourModel: a covariance is not positive definite; retrain with more labelled pixels per colour") from None
        object.__setattr__(self, "means", mu)
        object.__setattr__(self, "covariances", cov)
        object.__setattr__(self, "whiten", np.linalg.inv(L))
        # distances()'s whitening rows and offsets, fixed with the model (12 calls a frame)
        K = len(self.names)
        object.__setattr__(self, "_rows", self.whiten.transpose(1, 0, 2).reshape(3 * K, 3))
        object.__setattr__(self, "_offsets", np.einsum("kij,kj->ik", self.whiten, self.means).reshape(3 * K).astype(np.float32))

    @property
    def n_colours(self) -> int:
        return len(self.names)

    def distances(self, linear_rgb: np.ndarray, W: np.ndarray | None = None) -> np.ndarray:
        """Mahalanobis distance ``(N, K)`` of every pixel ``(N, 3)`` (white-balanced by ``W``) to every colour."""
        x = np.asarray(linear_rgb, np.float32).reshape(-1, 3)
        K = self.n_colours
        # rows of A: whitening component c of colour k at row c * K + k (so the three
        # components of all colours are contiguous column blocks of y)
        A = self._rows
        if W is not None:
            A = A @ np.asarray(W, float)
        y = x @ A.T.astype(np.float32)
        return _block_norms(y, self._offsets, K)

    def save(self, path: str | Path) -> None:
        np.savez(path, means=self.means, covariances=self.covariances, names=np.array(self.names))

    @classmethod
    def load(cls, path: str | Path) -> "ColourModel":
        z = read_npz(path, ("means", "covariances", "names"), "colour model",
                     "give the colour model a run wrote (shirt/colour_model.npz; ColourModel.save)")
        return cls(z["means"], z["covariances"], tuple(str(s) for s in z["names"]))


@numba.njit(cache=True, nogil=True)
def _block_norms(y, b, K):  # pragma: no cover
    """``(n, K)`` float32 from ``y (n, 3K)`` float32 and ``b (3K,)`` float32: numpy's ``y -= b; y *= y;
    d = y[:, :K] + y[:, K:2K]; d += y[:, 2K:]; sqrt(d)``, element by element in float32 (one pass
    instead of five over the crop's pixels)."""
    n = y.shape[0]
    d = np.empty((n, K), np.float32)
    for i in range(n):
        for k in range(K):
            u = y[i, k] - b[k]
            v = y[i, K + k] - b[K + k]
            w = y[i, 2 * K + k] - b[2 * K + k]
            d[i, k] = np.sqrt((u * u + v * v) + w * w)
    return d


def _eroded_labels(labels: np.ndarray, n_colours: int, erode_px: int) -> np.ndarray:
    """Labels with each colour's region shrunk by ``erode_px`` (borders and blur left out)."""
    lab = np.asarray(labels)
    if erode_px <= 0:
        return lab
    out = np.full(lab.shape, -1, lab.dtype)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * erode_px + 1, 2 * erode_px + 1))
    for k in range(n_colours):
        m = cv2.erode((lab == k).astype(np.uint8), kernel)
        out[m > 0] = k
    return out


def _medians_by_label(lab: np.ndarray, px: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Per-channel median ``(K, 3)`` of the pixels ``px (n, 3)`` float32 of every label ``lab (n,)`` (``counts`` per
    label): ``np.median`` of each label's pixels, for all labels at once (one sort per channel).

    The same values as np.median: the middle value, or the float32 mean ``(a + b) / 2`` of the two
    middle ones (for one middle value that is the value itself).  Labels without pixels give garbage.
    """
    px = np.asarray(px, np.float32)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    lo = starts + np.maximum(counts - 1, 0) // 2
    hi = starts + counts // 2
    n = len(lab)
    lo, hi = np.minimum(lo, max(n - 1, 0)), np.minimum(hi, max(n - 1, 0))
    out = np.zeros((len(counts), 3))
    if n == 0:
        return out
    for c in range(3):
        v = px[np.lexsort((px[:, c], lab)), c]
        out[:, c] = np.true_divide(v[lo] + v[hi], 2)
    return out


def labelled_colour_means(image: np.ndarray, labels: np.ndarray, n_colours: int, erode_px: int = 1,
                          min_pixels: int = 8, robust: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Mean linear colour of each labelled colour.

    Parameters
    ----------
    image : (H, W, 3) uint8 sRGB, or float linear RGB
    labels : (H, W) int
        Colour id per pixel (user scribbles or a rendered id map), -1 elsewhere.
    robust : bool
        Per-channel medians instead of means: labels from a rendered pose that is a few
        pixels off put some pixels of a neighbouring patch under a colour.

    Returns
    -------
    means : (K, 3) float
        NaN rows for colours with fewer than ``min_pixels`` labelled pixels.
    counts : (K,) int
    """
    img = to_linear(image) if np.asarray(image).dtype == np.uint8 else np.asarray(image, np.float32)
    lab = _eroded_labels(labels, n_colours, erode_px).ravel()
    ok = (lab >= 0) & (lab < n_colours)
    lab = lab[ok].astype(np.int64)
    px = img.reshape(-1, 3)[ok]
    counts = np.bincount(lab, minlength=n_colours)
    sums = np.stack([np.bincount(lab, weights=px[:, c], minlength=n_colours) for c in range(3)], axis=1)
    means = np.full((n_colours, 3), np.nan)
    good = counts >= min_pixels
    if robust:
        means[good] = _medians_by_label(lab, px, counts)[good]
    else:
        means[good] = sums[good] / counts[good, None]
    return means, counts


def train_colour_model(images: list[np.ndarray], labels: list[np.ndarray], names: tuple[str, ...], erode_px: int = 2,
                       min_pixels: int = 50, regularisation: float = 1e-6) -> ColourModel:
    """Fit one Gaussian per colour to the labelled pixels of white-balanced images.

    Parameters
    ----------
    images : list of (H, W, 3) uint8 sRGB
    labels : list of (H, W) int
        Colour id per pixel, -1 for unlabelled.
    names : tuple[str, ...]
        Colour names (K of them).
    erode_px : int
        Labelled regions are shrunk by this much (their borders mix colours).

    Raises
    ------
    MocapInputError
        When a colour has fewer than ``min_pixels`` labelled pixels.
    """
    K = len(names)
    if len(images) != len(labels) or not images:
        raise MocapInputError(f"train_colour_model: {len(images)} images and {len(labels)} label maps; give one label map per image")
    xs: list[list[np.ndarray]] = [[] for _ in range(K)]
    for img, lab in zip(images, labels):
        if np.asarray(img).shape[:2] != np.asarray(lab).shape:
            raise MocapInputError(f"train_colour_model: image {np.shape(img)} and labels {np.shape(lab)} differ in size")
        lin = to_linear(img).reshape(-1, 3)
        er = _eroded_labels(lab, K, erode_px).ravel()
        for k in range(K):
            xs[k].append(lin[er == k])
    means = np.zeros((K, 3))
    covs = np.zeros((K, 3, 3))
    for k in range(K):
        x = np.concatenate(xs[k]).astype(np.float64)
        if len(x) < min_pixels:
            raise MocapInputError(f"train_colour_model: colour {names[k]!r} has {len(x)} labelled pixels, need {min_pixels}; label more of it")
        means[k] = x.mean(axis=0)
        covs[k] = np.cov(x.T) + regularisation * np.eye(3)
    return ColourModel(means, covs, tuple(names))


def solve_white_balance(observed: np.ndarray, reference: np.ndarray, weights: np.ndarray | None = None,
                        min_colours: int = 3, whiten: np.ndarray | None = None) -> np.ndarray | None:
    """3x3 ``W`` with ``W @ observed_k ~ reference_k`` in least squares.

    Parameters
    ----------
    observed : (K, 3) float
        Mean linear colours under the current light (NaN rows are skipped).
    reference : (K, 3) float
        The colour model's means.
    weights : (K,) float, optional
        Per-colour weights (e.g. square roots of pixel counts).
    min_colours : int
        With fewer usable colours a diagonal ``W`` (per-channel gains) is solved, and
        with none at all the result is None.
    whiten : (K, 3, 3) float, optional
        ``L_k^-1`` of each colour's covariance (:attr:`ColourModel.whiten`): the residual
        of colour ``k`` is then measured as the classifier measures it, in its own
        Mahalanobis metric (generalised least squares).  Plain least squares weighs every
        channel of every colour alike, so it fits the bright colours and leaves the dark
        ones (blue, purple under a tungsten lamp) several standard deviations from their
        Gaussians, where the classifier's threshold rejects them; in the Mahalanobis
        metric the same labelled frame classifies about 0.9 of its shirt pixels correctly
        instead of 0.35 (shirt_tungsten_off, frame 0).

    Returns
    -------
    (3, 3) float or None
    """
    obs = np.asarray(observed, float)
    ref = np.asarray(reference, float)
    ok = np.all(np.isfinite(obs), axis=1)
    if weights is not None:
        ok &= np.asarray(weights) > 0
    if not ok.any():
        return None
    w = np.ones(len(obs)) if weights is None else np.asarray(weights, float)
    A, B, ww = obs[ok], ref[ok], w[ok][:, None]
    # whitened residual of colour k: w_k L_k^-1 (W o_k - mu_k), linear in the unknowns:
    # W o_k = kron(I3, o_k^T) vec(W) (row-major vec), or diag(o_k) g for per-channel gains;
    # plain least squares is the same with L_k = I
    Li = np.broadcast_to(np.eye(3), (len(A), 3, 3)) if whiten is None else np.asarray(whiten, float)[ok]
    diagonal = ok.sum() < min_colours
    if diagonal:
        M = Li * A[:, None, :]  # L^-1 diag(o)
    else:
        M = np.einsum("mij,mk->mijk", Li, A).reshape(len(A), 3, 9)  # L^-1 kron(I3, o^T)
    rhs = np.einsum("mij,mj->mi", Li, B)
    x, *_ = np.linalg.lstsq((M * ww[:, :, None]).reshape(-1, M.shape[2]), (rhs * ww).ravel(), rcond=None)
    return np.diag(x) if diagonal else x.reshape(3, 3)


def train_other_colours(images: list[np.ndarray], labels: list[np.ndarray], white_balance: list[np.ndarray],
                        rng: np.random.Generator, n_clusters: int = 6, max_pixels: int = 30000,
                        regularisation: float = 1e-5) -> ColourModel | None:
    """Gaussians of the session's *other* colours (trousers, skin, walls) from the labelled first frames.

    Not in seed 001: the bench's shirt has two achromatic patches (light grey and
    black), and under shading a dark-grey pair of trousers or a grey wall lies within
    three standard deviations of them.  Pixels labelled :data:`NOT_SHIRT` are white
    balanced with their camera's ``W`` and clustered (k-means, ``scipy.cluster.vq``)
    into ``n_clusters`` Gaussians; the classifiers then leave a pixel unclassified when
    one of these is nearer than every shirt colour.

    Returns
    -------
    ColourModel or None
        None when fewer than 100 pixels are labelled not-shirt.
    """
    xs = []
    for img, lab, W in zip(images, labels, white_balance):
        m = np.asarray(lab) == NOT_SHIRT
        if m.any():
            xs.append(to_linear(img)[m] @ np.asarray(W, np.float32).T)
    if not xs:
        return None
    x = np.concatenate(xs).astype(np.float64)
    if len(x) < 100:
        return None
    if len(x) > max_pixels:
        x = x[rng.choice(len(x), max_pixels, replace=False)]
    k = min(n_clusters, len(x) // 50)
    _, lab = kmeans2(x, k, minit="++", seed=rng)
    means, covs, names = [], [], []
    for c in range(k):
        xc = x[lab == c]
        if len(xc) < 20:
            continue
        means.append(xc.mean(axis=0))
        covs.append(np.cov(xc.T) + regularisation * np.eye(3))
        names.append(f"other_{c}")
    if not means:
        return None
    return ColourModel(np.array(means), np.array(covs), tuple(names))


class ReferenceIlluminations:
    """The white-balance matrices met so far (section 5.2, step 5).

    A new matrix joins when its Frobenius distance to every stored one exceeds
    ``min_distance`` (0.5 in the paper).
    """

    def __init__(self, first: np.ndarray, min_distance: float = 0.5, max_count: int = 32) -> None:
        self.min_distance = float(min_distance)
        self.max_count = int(max_count)
        self.matrices: list[np.ndarray] = [np.asarray(first, float).copy()]

    def __len__(self) -> int:
        return len(self.matrices)

    def offer(self, W: np.ndarray) -> bool:
        """Store ``W`` if it is new; returns whether it was stored."""
        W = np.asarray(W, float)
        if not np.all(np.isfinite(W)):
            return False
        d = min(float(np.linalg.norm(W - M)) for M in self.matrices)
        if d > self.min_distance and len(self.matrices) < self.max_count:
            self.matrices.append(W.copy())
            return True
        return False


def initial_white_balance(image: np.ndarray, labels: np.ndarray, colour_model: ColourModel) -> np.ndarray:
    """``W`` from one labelled frame (section 5.1): the user's scribbles, as colour ids per pixel (-1 unlabelled,
    :data:`mocap.shirt.colour_model.NOT_SHIRT` for not-shirt pixels, which are ignored here).

    Least squares on the labelled colours' means, each residual in its colour's
    Mahalanobis metric (:func:`mocap.shirt.colour_model.solve_white_balance`).

    Raises
    ------
    MocapInputError
        When no colour has enough labelled pixels.
    """
    means, counts = labelled_colour_means(image, labels, colour_model.n_colours, erode_px=1)
    W = solve_white_balance(means, colour_model.means, np.sqrt(counts), whiten=colour_model.whiten)
    if W is None:
        raise MocapInputError("initial white balance: no shirt colour has enough labelled pixels; scribble on more patches of the first frame")
    return W
