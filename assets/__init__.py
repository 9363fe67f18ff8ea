"""Robot models (URDF + generated meshes), shipped inside the package as ``annotator.assets``."""
