"""The capture's own photos: importers for the usual posed-photo formats, writers to convert between
them, and a check that the mesh sits where the cameras see it.

Every importer returns a :class:`PhotoSet` whose cameras follow scantex's one convention (OpenCV,
world frame = the mesh's); each format's module docstring says exactly how it is converted:

- :mod:`~scantex.photos.nerfstudio` ``transforms.json``,
- :mod:`~scantex.photos.colmap` ``cameras``/``images`` ``.txt`` and ``.bin``,
- :mod:`~scantex.photos.scannerapp` 3D Scanner App "All Data" frames,
- :mod:`~scantex.photos.polycam` Polycam raw keyframes,
- :mod:`~scantex.photos.scannet` ScanNet's exported frames (``color/``, ``depth/``, ``pose/``, ``intrinsic/``),
- :mod:`~scantex.photos.rgbd_frames` RGB-D frames as files (``frame-000000.color.png``, ``.depth.png``,
  ``.pose.txt``: Intrinsic3D, a ``.sens`` export, 3RScan, 3DMatch),
- :mod:`~scantex.photos.arkitscenes` ARKitScenes' captures (iPad Pro LiDAR scans: ``lowres_wide.traj``, ``.pincam``),
- :mod:`~scantex.photos.mve` texrecon's scene folder (photos beside ``.cam`` files; G2LTex's too),
- :mod:`~scantex.photos.mve_scene` MVE's scene (``views/view_0000.mve/meta.ini``),
- :mod:`~scantex.photos.metashape` Agisoft Metashape's cameras XML,
- :mod:`~scantex.photos.meshroom` Meshroom's (AliceVision's) ``cameras.sfm``,
- :mod:`~scantex.photos.openmvs` OpenMVS's ``scene.mvs``,
- :mod:`~scantex.photos.openmvg` OpenMVG's ``sfm_data.json``,
- :mod:`~scantex.photos.bundler` Bundler's ``bundle.out`` with its image list (RealityCapture's, Metashape's export),
- :mod:`~scantex.photos.nvm` VisualSfM's ``.nvm``,
- :mod:`~scantex.photos.realitycapture` RealityCapture's XMP sidecars (``<photo>.xmp``),
- :mod:`~scantex.photos.opensfm` OpenSfM's ``reconstruction.json`` (OpenDroneMap's ``opensfm/``),
- :mod:`~scantex.photos.cameras_json` scantex's own ``cameras.json``.

::

    photos = load_photos("capture/")          # any of the above
    require_alignment(scan, photos)           # ScanError when the mesh is not in the cameras' frame
    write_colmap_binary(photos, "as_colmap/")  # convert
"""

from scantex.photos.alignment import (
           AlignmentReport,
           PhotoAlignment,
           check_alignment,
           require_alignment,
)
from scantex.photos.arkitscenes import load_arkitscenes
from scantex.photos.bundler import load_bundler, write_bundler
from scantex.photos.cameras_json import load_cameras_json, write_cameras_json
from scantex.photos.colmap import load_colmap, write_colmap_binary, write_colmap_text
from scantex.photos.load import detect_format, load_photos
from scantex.photos.meshroom import load_meshroom, write_meshroom
from scantex.photos.metashape import load_metashape, write_metashape
from scantex.photos.mve import load_mve, write_mve
from scantex.photos.mve_scene import load_mve_scene, write_mve_scene
from scantex.photos.nerfstudio import load_nerfstudio, write_nerfstudio
from scantex.photos.nvm import load_nvm, write_nvm
from scantex.photos.openmvg import load_openmvg, write_openmvg
from scantex.photos.openmvs import load_openmvs, write_openmvs
from scantex.photos.opensfm import load_opensfm, write_opensfm
from scantex.photos.photoset import Distortion, PhotoSet
from scantex.photos.polycam import load_polycam, write_polycam
from scantex.photos.realitycapture import load_realitycapture, write_realitycapture
from scantex.photos.rgbd_frames import load_rgbd_frames
from scantex.photos.scannerapp import load_3dscannerapp, write_3dscannerapp
from scantex.photos.scannet import load_scannet

__all__ = ["AlignmentReport", "Distortion", "PhotoAlignment", "PhotoSet", "check_alignment", "detect_format",
           "load_3dscannerapp", "load_arkitscenes", "load_bundler", "load_cameras_json", "load_colmap",
           "load_meshroom", "load_metashape", "load_mve", "load_mve_scene", "load_nerfstudio", "load_nvm",
           "load_openmvg", "load_openmvs", "load_opensfm", "load_photos", "load_polycam", "load_realitycapture",
           "load_rgbd_frames", "load_scannet", "require_alignment", "write_3dscannerapp", "write_bundler",
           "write_cameras_json", "write_colmap_binary", "write_colmap_text", "write_meshroom", "write_metashape",
           "write_mve", "write_mve_scene", "write_nerfstudio", "write_nvm", "write_openmvg", "write_openmvs",
           "write_opensfm", "write_polycam", "write_realitycapture"]
