"""Photos or a video in, a COLMAP dataset out: structure from motion with pycolmap
(:mod:`.pipeline`), poses checked against the truth with :mod:`.align`."""
from .align import pose_errors, umeyama
from .pipeline import capture

__all__ = ["capture", "pose_errors", "umeyama"]
