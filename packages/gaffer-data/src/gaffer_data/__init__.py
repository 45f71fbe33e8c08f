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
    MultiviewConfig,
    RenderConfig,
    multiview_render_config,
)
from gaffer_data.dataset import (
    AuthorsDataset,
    AuthorsSample,
    RelightSample,
    RenderDataset,
    RenderedObject,
    open_authors_dataset,
    open_dataset,
    read_object,
)
from gaffer_data.errors import (
    ClusterError,
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
    "AuthorsDataset",
    "AuthorsSample",
    "BounceConfig",
    "CameraConfig",
    "ClusterError",
    "ConfigError",
    "GafferDataError",
    "GafferSchemaWarning",
    "InputError",
    "IntegrityError",
    "ManifestError",
    "MissingDependencyError",
    "MultiviewConfig",
    "RelightSample",
    "RenderConfig",
    "RenderDataset",
    "RenderError",
    "RenderedObject",
    "SchemaVersionError",
    "__version__",
    "multiview_render_config",
    "open_authors_dataset",
    "open_dataset",
    "read_object",
]
