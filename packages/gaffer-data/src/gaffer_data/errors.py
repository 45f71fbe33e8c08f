"""Errors raised by gaffer-data.

Every error names the argument or file at fault and says how to fix it. Concrete errors also subclass a
builtin (`ValueError`, `OSError`, `ImportError`, `RuntimeError`) so callers that do not know gaffer still
catch them sensibly. Errors that reach the command line implement `diagnostics()`.
"""

from gaffer_envmap.errors import GafferError


class GafferDataError(GafferError):
    """Base class of every gaffer-data error (`diagnostics()` comes from `gaffer_envmap.errors.GafferError`)."""


class SchemaVersionError(GafferDataError, ValueError):
    """A manifest has a different MAJOR schema version (or a different schema name) than this reader."""


class ManifestError(GafferDataError, ValueError):
    """A manifest is missing, not JSON, or lacks a required field."""


class IntegrityError(GafferDataError, ValueError):
    """A payload file is missing or its sha256 differs from the one recorded in the manifest."""


class ConfigError(GafferDataError, ValueError):
    """A configuration value is out of range or inconsistent."""


class InputError(GafferDataError, ValueError):
    """An input folder or file (objects, envmaps, annotations) is missing, empty or unsupported."""


class RenderError(GafferDataError, RuntimeError):
    """A Blender worker failed to render an object (after its retries)."""


class ClusterError(GafferDataError, ConnectionError):
    """The Ray cluster given to `--backend ray` cannot be reached."""


class MissingDependencyError(GafferDataError, ImportError):
    """An optional dependency is needed for this call; the message holds the exact pip command."""


class GafferSchemaWarning(UserWarning):
    """A manifest was written by a newer MINOR schema version; unknown fields are ignored."""


def missing_extra(module: str, extra: str) -> MissingDependencyError:
    """Build the error raised when `module` (from the `extra` of gaffer-data) cannot be imported.

    Args:
        module: the import name that failed, e.g. "bpy".
        extra: the gaffer-data extra that provides it, e.g. "render".

    Returns:
        A `MissingDependencyError` whose message holds the pip command to run.
    """
    return MissingDependencyError(
        f"`{module}` is not installed; it is needed for this call. "
        f'Install it with: pip install "gaffer-data[{extra}]"'
    )
