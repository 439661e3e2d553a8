"""The geometry of cameras and ports: the pinhole camera with OpenCV's distortion, the flat
port and the dome port, refraction and tracing through them, the forward projection and its
Jacobians, the closest points of two lines, the ports' exchange formats."""
