"""A user's own rig: multi-camera recordings of a person, in the formats users already have, as data sets.

A project folder::

    PROJECT/
      <calibration>              optional: the rig of every recording (see below)
      <recording>/               one folder per recording (a trial, a session) of that rig
        detections.npz           jaxpose's multi-view arrays (`jaxpose.formats.detections_npz`: keypoints
                                 [N, C, J, 2] px, camera_names, optional confidence, frames [N],
                                 image_size, skeleton, K/dist/distortion_model), or
        <camera>/ or <camera>_json/   one folder per camera of OpenPose-style JSON frames, or
        <camera>.json            one COCO keypoint-results file per camera (image_id = frame number)
        <calibration>            optional: this recording's own rig, overriding the project's
        ground_truth.npz         optional, evaluation only: points3d [N, J, 3] world mm (the
                                 calibration's world frame), frames [N], joint_names [J]

Calibrations (`jaxpose.formats.calibration_files`): a jaxpose camera file, an Anipose / Pose2Sim /
FreeMoCap TOML, or EasyMocap's intri.yml + extri.yml, found in a folder by their content.  Cameras
are matched to the detection folders by name (a folder's name without `_json`), ignoring case,
separators and leading zeros where that matches them one to one ("cam_01" is folder "cam01_json").  Without any
calibration the rig is recovered from the recordings (`jaxpose.calibrate`).

What loading does to each recording, in order (one recording at a time: `jaxpose.rig.preparation`):
1. reads every camera's detections (parsed once, then cached: `jaxpose.formats.keypoint_files`),
   and finds its calibration (`jaxpose.rig.recordings`, `jaxpose.rig.cameras`);
2. converts them from the detector's layout to its lifting skeleton (the detector's own joints,
   root first: `jaxpose.layouts.to_lifting_skeleton`); scores below `min_confidence` are
   treated as missing;
3. aligns the cameras in time: camera c's frame f shows instant f + offset[c]; offsets given, or
   estimated (`jaxpose.rig.timeline`); instants seen by no camera are absent, a
   camera without a frame at an instant has confidence 0 there; every instant goes further (the split
   and the strides are applied to the prepared instants: `jaxpose.rig.split`);
4. without any calibration, groups the recordings by rig (sessions: given by --data.sessions, else found
   from the data) and recovers each session's rig from its recordings (`jaxpose.rig.recovered`);
5. undistorts the keypoints with the calibration (the data sets' rigs are then pinhole);
6. keeps one person per instant, the one the views agree on (`jaxpose.rig.people`), and checks a
   calibration read without a stated unit against that person's limbs;
7. attaches the ground truth where there is one, over the joints it shares with the lifting
   skeleton by name (the derived root from the hips where the ground truth has both:
   `jaxpose.data.ground_truth`), moved into a recovered rig's world.

The settings of all this are `jaxpose.rig.config.RigProjectConfig` (the --data flags).  The result, every
instant of every recording, is prepared once: written to the project's cache
(``PROJECT/.jaxpose_cache/prepared-<key>/``, or --data.cache-dir, `jaxpose.rig.cache`) and memory-mapped
from there by every later run with the same inputs and options, whatever its split: the training and
validation parts are row selections of it (`jaxpose.rig.split`: held-out recordings or each
recording's final fraction, then the strides), and a temporal lifter's window is the neighbouring rows of the same
recording.  Every JSON file parsed is cached there too (`jaxpose.formats.keypoint_files`).  Steps 5 and 6
run in chunks of one fixed size across recordings (`jaxpose.rig.geometry`): the compilations of loading do
not grow with the number or the lengths of the recordings.
"""

from __future__ import annotations

from jaxpose.rig import cache
from jaxpose.rig.cache import PreparedProject
from jaxpose.rig.config import RigProjectConfig
from jaxpose.rig.preparation import prepare
from jaxpose.rig.recordings import FoundProject, find_project
from jaxpose.rig.split import RigProject, split


def load_rig_project(config: RigProjectConfig, progress: bool = True, found: FoundProject | None = None) -> RigProject:
    """Every recording of the project, read, aligned, calibrated and reduced to one person (see the module
    docstring), or all that from the cache, split into training and validation parts (`split`).  `found`:
    the project's files as found already (`jaxpose.rig.recordings.find_project`), else found now."""
    found = found or find_project(config.root, config.recordings, config.calibration)
    unknown = sorted(set(config.validation_recordings) - set(found.names))
    if unknown:  # before any work
        raise ValueError(f"--data.validation-recordings {unknown}: no such recording (have {list(found.names)})")
    return split(prepared_project(config, found, progress), config)


def prepared_project(config: RigProjectConfig, found: FoundProject, progress: bool = True, cached_only: bool = False) -> PreparedProject | None:
    """Every instant of the project from the cache, else prepared (and cached where the cache can be
    written); with `cached_only`, None where the cache does not hold it."""
    entry = cache.entry(config, found)
    prepared = cache.lookup(entry)
    if prepared is not None or cached_only:
        return prepared
    return prepare(config, found, progress, entry)
