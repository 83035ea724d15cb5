"""Vehicle catalog: URDF / mesh loading into the body frame, the generated catalog, held-out meshes.

Body frame (METHOD.md): +X forward, +Y left, +Z up, metres, origin at the centre of the
footprint on the ground. Other modules use ``vehicle.name``, ``vehicle.cls`` and ``vehicle.mesh``.
"""

from torch_atr.vehicles.catalog import load_catalog, load_catalog_folder, load_catalog_vehicle, load_heldout_meshes
from torch_atr.vehicles.loader import CLASS_NAMES, Vehicle, load_vehicle, vehicle_from_mesh

__all__ = ["CLASS_NAMES", "Vehicle", "load_vehicle", "vehicle_from_mesh", "load_catalog", "load_catalog_folder",
           "load_catalog_vehicle", "load_heldout_meshes"]
