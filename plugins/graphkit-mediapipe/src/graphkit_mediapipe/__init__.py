"""graphkit-mediapipe: the FaceMesh node (mediapipe 0.10.14 face mesh).

Registered through the ``graphkit.nodes`` entry point as a dict, so mediapipe is imported only
when a graph uses FaceMesh.
"""

NODES = {"FaceMesh": "graphkit_mediapipe.facemesh:FaceMesh"}
