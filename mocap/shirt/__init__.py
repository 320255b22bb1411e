"""Colour-shirt motion capture (seed 001: Wang, Paris & Popovic, *Practical Color-Based Motion Capture*).

One module per stage of the per-frame pipeline (:mod:`mocap.shirt.pipeline` runs them):

* :mod:`~mocap.shirt.background` — coarse background subtraction (MOG2);
* :mod:`~mocap.shirt.histogram_search` — where the shirt is (chromaticity-histogram uniformity, integral histogram);
* :mod:`~mocap.shirt.colour_model` — Gaussian colour model, white balance ``W``, reference illuminations;
* :mod:`~mocap.shirt.classify` — Gaussian (step 1) and pose-assisted (step 3) classification, patch centroids;
* :mod:`~mocap.shirt.pose_database` — tiny 40x40 id maps, nearest neighbours (faiss), blending (step 2);
* :mod:`~mocap.shirt.shirt_model` — the shirt posed and rasterised into id maps, from its meshes
  (:mod:`~mocap.shirt.geometry`), the upper body's Pinocchio kinematics (:mod:`~mocap.shirt.kinematics`)
  and a CPU z-buffer (:mod:`~mocap.shirt.zbuffer`);
* :mod:`~mocap.shirt.ik` — centroid IK with trained covariances (step 4; the 6-DoF fit of step 2).

Nothing here imports the simulator: the shirt's geometry and the humanoid's MJCF come
with the pose database file.
"""

from mocap.shirt.pipeline import STAGES, FrameEstimate, ShirtPipelineParams, ShirtTracker, initial_white_balance

__all__ = ["STAGES", "FrameEstimate", "ShirtPipelineParams", "ShirtTracker", "initial_white_balance"]
