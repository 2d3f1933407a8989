"""Frame sources: where RGB-D frames come from, and the publisher loop that sends them.

Every source is a ``FrameSource``: ``frames()`` yields ``ipc.RGBDFrame`` (rgb (H, W, 3)
uint8, depth_m (H, W) float32 metres registered to colour, CameraInfo of the colour
camera), ``depth_scale`` tells how to quantise depth on the wire, ``close()`` releases it.

- ``SequenceSource``: a recorded sequence folder.
- ``RealSenseSource``: an Intel RealSense camera (optional ``pyrealsense2``, extra "realsense").
- ``KinectSource``: an Azure Kinect, or a recording of one (optional ``pyk4a``, extra "kinect").
- ``RosbagSource``: a ROS 1/2 bag's Image and CameraInfo topics (optional ``rosbags``, extra "rosbag").

``publish_frames(source, publish, pacing=..., loop=...)`` paces frames to any callable;
``run_publisher(source, endpoint, ...)`` binds a ZeroMQ publisher and runs it. Optional
SDKs are imported when their source is made; a missing one raises ``SourceError`` naming
the extra to install. Command line: ``python -m launch_scripts.publish_frames``.

A simulated scene is a source too: ``sim.frame_source.SceneSource``, which lives with the
simulation so that nothing here depends on it (docs/architecture.md, "Adding a frame source").
"""

from perception.sources._base import FrameSource, Pacing, SourceError, publish_frames
from perception.sources._kinect import KinectSource
from perception.sources._publish import run_publisher
from perception.sources._realsense import RealSenseSource
from perception.sources._rosbag import RosbagSource
from perception.sources._sequence import SequenceSource

__all__ = [
    "FrameSource",
    "KinectSource",
    "Pacing",
    "RealSenseSource",
    "RosbagSource",
    "SequenceSource",
    "SourceError",
    "publish_frames",
    "run_publisher",
]
