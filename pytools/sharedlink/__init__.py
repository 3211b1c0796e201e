"""SharedLink tools: codec, stream state, capture generation and decoding helpers."""

from .codec import (
    Checksum,
    Field,
    Frame,
    SharedLinkError,
    build_frame,
    checksum,
    frame_kind,
    iter_segments,
    parse_frame,
    split_frames,
)

__all__ = [
    "Checksum",
    "Field",
    "Frame",
    "SharedLinkError",
    "build_frame",
    "checksum",
    "frame_kind",
    "iter_segments",
    "parse_frame",
    "split_frames",
]
__version__ = "0.1.0"
