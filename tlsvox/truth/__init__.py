"""The synthetic truth world: a procedural tree, a TLS scanner simulator, exact
leaf area per voxel.

- :mod:`tlsvox.truth.synthetic`: the seeded broadleaf tree (mesh + materials);
- :mod:`tlsvox.truth.scanner`: terrestrial scans of it on Open3D's ray caster;
- :mod:`tlsvox.truth.meshtruth`: the exact one-sided leaf area per voxel.

Open3D is imported only by the functions that need it.
"""
