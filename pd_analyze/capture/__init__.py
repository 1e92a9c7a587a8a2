"""The capture layer: frames read from pcap, pcapng and gzip files, one at a time."""

from pd_analyze.capture.raw import MAX_CAPLEN, CaptureError, CaptureInfo, RawFrame
from pd_analyze.capture.reader import cut_runs, frames

__all__ = ["MAX_CAPLEN", "CaptureError", "CaptureInfo", "RawFrame", "cut_runs", "frames"]
