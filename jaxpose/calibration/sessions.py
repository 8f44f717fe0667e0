"""Recordings grouped by rig: the sessions of a project whose cameras moved between recordings.

Labs record over days and cameras get bumped; a project's recordings then come from several rigs.
A session is a set of recordings one rig explains.  Two ways to find them:

- **From the folders** (`group_by_label`): the user's session label per recording (e.g. Pose2Sim's
  session folder), taken as given.
- **From the data** (`find_sessions`): a rig is recovered from each recording alone (`calibrate`);
  then every recording's detections are triangulated through every recovered rig (robust IRLS) and
  re-projected.  A rig explains a recording when, in every camera, the median re-projection error is
  at most `FIT_MARGIN_PX` above what the recording's own rig leaves (`rig_fit_px`): the detector's
  noise is in both, a moved camera only in the first.  Two recordings share a rig when either's rig
  explains the other (a rig recovered from a subject who stays on one spot can be degrees off and
  fail on the other recordings of its cameras, while their rigs still explain it).  Recordings are
  grouped by complete linkage: two groups merge only when every two of their recordings share a
  rig, so that a chain of near misses cannot join two rigs.  A recording whose own calibration fails
  (too short, too still) joins the session whose rigs explain it best, if any does; otherwise it fits
  no rig and is named in `SessionGrouping.unfitted`.  With `until_explained` (what the rig loader
  uses), rigs are recovered only until every recording is explained, the recordings where the
  person moves most first: a few calibrations for a project of many recordings and few rigs.

Why `FIT_MARGIN_PX` = 3 px: the detector's noise is in both fits, a moved camera only in the other
rig's.  A camera turned by 1 degree moves its image points by f tan(1 deg), 17-21 px at the
1,000-1,200 px focal lengths of HD cameras, and one moved 100 mm at 5 m about as much; the same
cameras recovered from two recordings differ by their estimation error, under 1 px where the
subject moves about.  Measured on four simulated two-rig projects (docs/calibration.md, "Sessions"):
own fits 4.1-5.6 px with the default detector's 3-8 px noise (8.0 for a failed rig), the same
cameras' rig from another recording within 0.3 px of them where the subject walks (2.0-3.0 px for
rigs recovered from a subject on one spot, hence the either-way rule), a rig moved by 100-500 mm and
1-3 degrees per camera over 100 px.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose.calibration import Calibration, CalibrationConfig, CalibrationError, RigDetections, calibrate
from jaxpose.camera import Cameras, projection_matrices, undistort_points
from jaxpose.robust import irls_triangulate, reprojection_residuals

FIT_MARGIN_PX = 3.0


@dataclasses.dataclass(frozen=True)
class Session:
    name: str
    recordings: tuple[str, ...]
    reprojection_px: float | None
    """The largest, over the session's recordings, of their worst camera's median re-projection error
    through their own rig (None for sessions given by label, which are not calibrated here)."""


@dataclasses.dataclass(frozen=True)
class SessionGrouping:
    """The sessions of a project's recordings, how they were found, and the evidence."""

    sessions: tuple[Session, ...]
    unfitted: tuple[str, ...]
    """Recordings no rig explains (their own calibration failed and no other rig fits them)."""
    method: str
    """"labels" (the user's) or "data" (`find_sessions`)."""
    recordings: tuple[str, ...] = ()
    fit_px: np.ndarray | None = None
    """f64[R, R]: [i, j] the worst camera's median re-projection error (px) of recording j's detections
    through recording i's rig (NaN where i has no rig), recordings in `recordings`' order."""
    failures: Mapping[str, str] = dataclasses.field(default_factory=dict)
    """Recording -> why its own calibration failed."""
    calibrations: Mapping[str, Calibration] = dataclasses.field(default_factory=dict)
    """Recording -> the rig recovered from it alone (`find_sessions`)."""

    def session_of(self, recording: str) -> str | None:
        return next((session.name for session in self.sessions if recording in session.recordings), None)


def group_by_label(names: Sequence[str], labels: Sequence[str]) -> SessionGrouping:
    """Sessions from the user's labels, one per distinct label (in order of first appearance)."""
    if len(names) != len(labels):
        raise ValueError(f"group_by_label: {len(names)} recordings but {len(labels)} session labels")
    if len(set(names)) != len(names):
        raise ValueError(f"group_by_label: recording names repeat: {sorted(n for n in set(names) if list(names).count(n) > 1)}")
    sessions = tuple(
        Session(label, tuple(name for name, own in zip(names, labels) if own == label), None) for label in dict.fromkeys(labels)
    )
    return SessionGrouping(sessions=sessions, unfitted=(), method="labels", recordings=tuple(names))


def rig_fit_px(cameras: Cameras, detections: RigDetections, min_confidence: float = 0.3) -> np.ndarray:
    """f64[C] per camera, the median re-projection error (px, undistorted) of the detections triangulated
    through `cameras` (robust IRLS), over the joints detected in two views or more; NaN for a camera
    with no such detection."""
    confidence = np.where(detections.confidence >= min_confidence, detections.confidence, 0.0).astype(np.float32)
    confidence = np.where((confidence > 0).sum(1, keepdims=True) >= 2, confidence, 0.0)
    lens = jax.tree.map(lambda field: jnp.asarray(field, jnp.float32), cameras)
    residual = np.asarray(_residuals(lens, jnp.asarray(detections.keypoints, jnp.float32), jnp.asarray(confidence)), np.float64)
    seen = confidence > 0
    return np.array([np.median(residual[:, c][seen[:, c]]) if seen[:, c].any() else np.nan for c in range(residual.shape[1])])


def pooled_detections(recordings: Mapping[str, RigDetections], names: Sequence[str]) -> RigDetections:
    """The detections of the recordings `names` (one session) as one `RigDetections`, frames one after
    the other, to recover the session's rig from all of them (`calibrate`); cameras, image sizes,
    skeleton and intrinsics are the first recording's, and the others must name the same cameras."""
    chosen = [recordings[name] for name in names]
    first = chosen[0]
    for name, detections in zip(names, chosen):
        if detections.camera_names != first.camera_names or detections.skeleton != first.skeleton:
            raise ValueError(
                f"pooled_detections: recording {name!r} has cameras {detections.camera_names} ({detections.skeleton.name}),"
                f" {names[0]!r} has {first.camera_names} ({first.skeleton.name})"
            )
    return dataclasses.replace(
        first,
        keypoints=np.concatenate([detections.keypoints for detections in chosen]),
        confidence=np.concatenate([detections.confidence for detections in chosen]),
        source=f"session of {', '.join(names)}",
    )


@jax.jit
def _residuals(cameras: Cameras, keypoints: jax.Array, confidence: jax.Array) -> jax.Array:
    """f32[N, C, J] re-projection errors (px) of the detections triangulated through `cameras` [C]."""
    pixels = undistort_points(cameras, keypoints)
    P = projection_matrices(cameras)
    points, _ = irls_triangulate(P, pixels, confidence)
    return reprojection_residuals(P, pixels, points)


def find_sessions(
    recordings: Mapping[str, RigDetections],
    config: CalibrationConfig = CalibrationConfig(),
    margin_px: float = FIT_MARGIN_PX,
    until_explained: bool = False,
) -> SessionGrouping:
    """Sessions found from the data (see the module docstring); `recordings` maps names to the detections
    of one recording each, all of the same cameras in the same order.

    `until_explained`: instead of a rig from every recording, rigs from the recordings in order of how
    much the person moves in them (`motion`: the best rigs first), until every recording has a rig or
    is explained by one (within `margin_px` of what that rig leaves on its own recording); the others
    then join sessions as recordings without a rig of their own do.  A project of many recordings and
    few rigs costs a few calibrations instead of one per recording."""
    names = tuple(recordings)
    if not names:
        raise ValueError("find_sessions: no recordings")
    cameras = {detections.camera_names for detections in recordings.values()}
    if len(cameras) != 1:
        raise ValueError(f"find_sessions: the recordings name different cameras: {sorted(cameras)}")
    rigs: dict[str, Calibration] = {}
    failures = {}
    fit = np.full((len(names), len(names)), np.nan)

    def recover(rig_name: str) -> None:
        try:
            rigs[rig_name] = calibrate(recordings[rig_name], config)
        except CalibrationError as error:
            failures[rig_name] = str(error)
            return
        for j, name in enumerate(names):
            fit[names.index(rig_name), j] = np.nanmax(rig_fit_px(rigs[rig_name].cameras, recordings[name], config.min_confidence))

    order = sorted(names, key=lambda name: -motion(recordings[name], config.min_confidence)) if until_explained else names
    for rig_name in order:
        if not (until_explained and _explained(fit, names.index(rig_name), margin_px)):
            recover(rig_name)
    grouping = group_by_fit(names, fit, margin_px)
    # A recording some rig explained joins a session only where all of that session's rigs explain it:
    # one that none does gets its own rig after all, before anything is called unfitted.
    while untried := [name for name in order if name in grouping.unfitted and name not in rigs and name not in failures]:
        recover(untried[0])
        grouping = group_by_fit(names, fit, margin_px)
    return dataclasses.replace(grouping, failures=failures, calibrations=rigs)


def motion(detections: RigDetections, min_confidence: float = 0.3) -> float:
    """How much the person moves in `detections`: the keypoints' spread over time (px), median over
    joints and views (`calibrate` refuses a recording where it is under 1% of the image diagonal)."""
    seen = detections.confidence >= min_confidence
    positions = np.where(seen[..., None], detections.keypoints, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a joint never seen by a view: all-NaN
        spread = np.sqrt(np.sum(np.nanvar(positions, axis=0), axis=-1))
        value = float(np.nanmedian(spread))
    return value if np.isfinite(value) else 0.0


def _explained(fit: np.ndarray, j: int, margin_px: float) -> bool:
    """Whether some rig of `fit`'s rows explains recording j: its error there within `margin_px` of what
    that rig leaves on its own recording."""
    own = np.diag(fit)
    return bool((fit[:, j] <= own + margin_px).any())


def group_by_fit(names: Sequence[str], fit: np.ndarray, margin_px: float = FIT_MARGIN_PX) -> SessionGrouping:
    """Sessions from the fit matrix (`SessionGrouping.fit_px`: [i, j] recording j through recording i's
    rig, a NaN row for a recording without a rig), as the module docstring says."""
    names = tuple(names)
    fit = np.asarray(fit, np.float64)
    if fit.shape != (len(names), len(names)):
        raise ValueError(f"group_by_fit: fit must be [{len(names)}, {len(names)}] for {len(names)} recordings, got {fit.shape}")
    own = np.diag(fit)
    has_rig = np.isfinite(own)
    # Rig i explains recording j when j's error through it is within the margin of what j's own rig
    # leaves; for a recording without a rig of its own, of what rig i leaves on its own recording.
    explains = fit <= own[None, :] + margin_px  # [i, j] (NaN compares False)
    explains[:, ~has_rig] = (fit <= own[:, None] + margin_px)[:, ~has_rig]
    # One rig filmed i and j when either recording's rig explains the other's detections: a rig
    # recovered from a weak recording (a subject on one spot) can be off by degrees and fail on a
    # recording of the same cameras, while the better rig still explains the weak recording.
    together = explains | explains.T

    groups = [[i] for i in range(len(names)) if has_rig[i]]
    while True:  # complete linkage: merge the two groups of smallest worst fit whose rigs all explain each other
        best = None
        for a in range(len(groups)):
            for b in range(a + 1, len(groups)):
                members = groups[a] + groups[b]
                if together[np.ix_(members, members)].all():
                    worst = np.max(fit[np.ix_(members, members)])
                    if best is None or worst < best[0]:
                        best = (worst, a, b)
        if best is None:
            break
        _, a, b = best
        groups[a] += groups.pop(b)
    unfitted = []
    for j in (j for j in range(len(names)) if not has_rig[j]):  # no rig of its own: the best-fitting session
        candidates = []
        for index, group in enumerate(groups):
            rigged = [i for i in group if has_rig[i]]  # the session's rigs: an earlier rigless member has no fits
            if explains[rigged, j].all():
                candidates.append((np.max(fit[rigged, j]), index))
        if candidates:
            groups[min(candidates)[1]].append(j)
        else:
            unfitted.append(names[j])
    sessions = tuple(
        Session(
            f"session{index + 1}",
            tuple(names[j] for j in sorted(group)),
            float(np.nanmax([own[j] for j in group])) if has_rig[group].any() else None,
        )
        for index, group in enumerate(sorted(groups, key=min))
    )
    return SessionGrouping(sessions, tuple(unfitted), "data", names, fit)
