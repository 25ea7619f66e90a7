"""graphkit-opencl: OpenCL backends for relightkit node types (the example backend plugin).

The engine finds this package through the ``graphkit.backends`` entry point declared in
``pyproject.toml``, which points at :data:`BACKENDS` below.  Mapping ``"NodeType/backend"`` to
``"module:Class"`` (instead of pointing at the classes) keeps discovery cheap: nothing here
imports pyopencl until a graph actually uses a backend.
"""

BACKENDS = {
    "RatioImage/opencl": "graphkit_opencl.ratio:RatioImageOpenCL",
    "KMStack/opencl": "graphkit_opencl.km:KMStackOpenCL",
    "LocalHistMatch/opencl": "graphkit_opencl.histmatch:LocalHistMatchOpenCL",
    "SkinShade/opencl": "graphkit_opencl.sss:SkinShadeOpenCL",
    "CosmeticShade/opencl": "graphkit_opencl.sss:CosmeticShadeOpenCL",
    "Relight/opencl": "graphkit_opencl.relight:RelightOpenCL",
}

__version__ = "0.1.0"
