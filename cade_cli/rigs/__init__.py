"""Camera rigs: the rig model and its file (:mod:`.rig`), calibration from chessboard views
(:mod:`.calibration`), rectification and its self-check (:mod:`.rectification`), one rectified
pair of a rig (:mod:`.pair`), multi-camera arrays registered onto a reference band (:mod:`.array`)."""
