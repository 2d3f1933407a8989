"""Messages, codec and ZeroMQ transport shared by every process of the toolkit."""

from ipc.messages import SCHEMA_VERSION, CameraInfo, GraspPlan, MeshEstimate, RGBDFrame

__all__ = ["SCHEMA_VERSION", "CameraInfo", "GraspPlan", "MeshEstimate", "RGBDFrame"]
