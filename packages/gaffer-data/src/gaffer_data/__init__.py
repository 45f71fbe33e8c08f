"""gaffer-data: filter 3D objects and render relighting datasets with Blender; read them without it.

The top level re-exports the pure parts (config, reader, errors). Rendering lives in
`gaffer_data.render` (Blender worker subprocesses) and filtering in `gaffer_data.filter`.
"""

from gaffer_data._version import __version__
from gaffer_data.config import (
    AreaLightConfig,
    AugmentConfig,
    BounceConfig,
    CameraConfig,
    RenderConfig,
)
from gaffer_data.dataset import (
    RelightSample,
    RenderDataset,
    RenderedObject,
    open_dataset,
    read_object,
)
from gaffer_data.errors import (
    ConfigError,
    GafferDataError,
    GafferSchemaWarning,
    InputError,
    IntegrityError,
    ManifestError,
    MissingDependencyError,
    RenderError,
    SchemaVersionError,
)

__all__ = [
    "AreaLightConfig",
    "AugmentConfig",
    "BounceConfig",
    "CameraConfig",
    "ConfigError",
    "GafferDataError",
    "GafferSchemaWarning",
    "InputError",
    "IntegrityError",
    "ManifestError",
    "MissingDependencyError",
    "RelightSample",
    "RenderConfig",
    "RenderDataset",
    "RenderError",
    "RenderedObject",
    "SchemaVersionError",
    "__version__",
    "open_dataset",
    "read_object",
]
