"""Calibration: boards, the cameras in air (:mod:`.air`), the housing underwater
(:mod:`.housing` over the flat-port and dome problems :mod:`.flat`, :mod:`.dome`), their
covariances, self-calibration from matched targets, the water index."""
