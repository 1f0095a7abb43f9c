"""Forward operators: photons from a point light through printed glass onto a receiver.

Subpackages by what they model: ``heightfield`` (the printed substrate alone), ``mesh`` (optical
elements as triangle meshes around it), ``optics`` and ``splat`` (ray optics with photon
differentials and their splatting, shared by both), ``kernels`` (backend support of the native
kernels). Within a subpackage, ``*_reference`` modules are the plain PyTorch paths the tests
compare against, ``*_native`` the numba kernels and ``*_cuda`` the GPU ones. Importing this package
loads none of them.
"""
