"""The capture layer: frames read from pcap, pcapng and gzip files, one at a time."""

from pd_analyze.capture.reader import (
    MAX_CAPLEN,
    CaptureError,
    CaptureInfo,
    RawFrame,
    cut_runs,
    frames,
    pcap_frames_from,
    pcap_split_points,
)

__all__ = ["MAX_CAPLEN", "CaptureError", "CaptureInfo", "RawFrame", "cut_runs", "frames",
           "pcap_frames_from", "pcap_split_points"]
