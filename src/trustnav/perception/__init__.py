"""Image -> people -> per-track observations for trustnav.trust. Never imports trustnav.control.

- :mod:`~trustnav.perception.types`: :class:`Person` (box, 17 COCO keypoints, confidences, score),
  the :class:`PoseBackend` protocol;
- :mod:`~trustnav.perception.mediapipe_backend`: default backend, multi-person BlazePose offline;
- :mod:`~trustnav.perception.optional_backends`: OpenPifPaf, ultralytics YOLO-pose (lazy imports);
- :mod:`~trustnav.perception.confidence`: occlusion-aware face keypoint confidences;
- :mod:`~trustnav.perception.looking`: the LOOKING eye-contact model in numpy (C_eye, `eye_score`);
- :mod:`~trustnav.perception.phone`: pose-geometry smartphone use (C_sm, `smato_score`);
- :mod:`~trustnav.perception.tracking`: OC-SORT / ByteTrack IDs;
- :mod:`~trustnav.perception.pipeline`: frame -> tracked people -> trust observations; sequences;
- :mod:`~trustnav.perception.frames`: image files, folders, videos.

Submodules are imported on use: mediapipe and the tracker load only when a backend or tracker is made.
"""
