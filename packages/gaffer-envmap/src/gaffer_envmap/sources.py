"""Pluggable lighting sources: text-to-HDR and light-estimation models as Python entry points.

A *source* turns words or a photo into an HDR environment map. gaffer finds sources through the
entry-point group `gaffer.envmap_sources` (`ENTRY_POINT_GROUP`): any installed distribution may
register one, and `gaffer-envmap sky --source NAME`, `gaffer-diffusion insert --light-source NAME` and
`gaffer-envmap sources` (the list) use it. gaffer-envmap registers its own phrase grammar as the
source "sky" (`gaffer_envmap.builtin_sources`) through the same mechanism.

A plugin's entry point names an `EnvmapSource`, or a callable without arguments that returns one (so
the plugin's module can stay cheap to import). A model should load its weights inside `from_text` /
`from_photo`, from a local path it takes as an option (`--source-option weights=/path`), never from the
network. Every map a source returns is checked here (`validate_source_map`): a `[He, 2*He, 3]` array
or `EnvironmentMap`, finite and non-negative (`gaffer_envmap.sanitize`), resampled to the width asked
for (power-exact) and converted to the Blender convention when it says it is in another.

Frames (both in the Blender convention: world z up, `gaffer_envmap.conventions`):

- `from_text`: a world map, as `gaffer-envmap sky` writes them.
- `from_photo`: the light around the camera that took the photo, for a level camera looking along
  world +y (the map's column u = 0.25 is straight ahead, u = 0.5 is the camera's right, +x), as
  `gaffer_diffusion.insert_geometry.light_from_photo` builds it. A DiffusionLight-style chrome-ball
  estimate in the camera's frame is turned into this by a roll of the columns.

Example:
    >>> import numpy as np
    >>> flat = EnvmapSource(
    ...     name="flat",
    ...     from_text=lambda text, *, width, options: np.ones((width // 2, width, 3), np.float32),
    ... )
    >>> env = envmap_from_text(flat, "anything", width=16)
    >>> env.radiance_linear.shape, env.metadata["gaffer:source"]
    ((8, 16, 3), 'flat')
"""

import importlib.metadata
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Literal, Protocol, runtime_checkable

import numpy as np

from gaffer_envmap.environment_map import EnvironmentMap
from gaffer_envmap.errors import EnvmapSourceError, GafferError, NonFiniteError
from gaffer_envmap.sanitize import SanitizePolicy, sanitize

__all__ = [
    "ENTRY_POINT_GROUP",
    "Capability",
    "EnvmapSource",
    "PhotoToEnvmap",
    "SourceEntry",
    "TextToEnvmap",
    "envmap_from_photo",
    "envmap_from_text",
    "envmap_sources",
    "format_source_list",
    "load_envmap_source",
    "parse_source_options",
    "validate_source_map",
]

ENTRY_POINT_GROUP = "gaffer.envmap_sources"
"""The entry-point group gaffer reads lighting sources from."""

Capability = Literal["text", "photo"]
"""What a source can start from: words (`from_text`) or a photo (`from_photo`)."""

_NAME = re.compile(r"^[a-z0-9][a-z0-9._-]*$")


@runtime_checkable  # checked at run time (the tests' beartype hook): any callable passes
class TextToEnvmap(Protocol):
    """`from_text(text, *, width, options)`: an HDR world map `[width // 2, width, 3]` for the words.

    It may return an `EnvironmentMap` or a float array; any size 2:1 map is resampled to `width`.
    `options` holds only the names the source declares in `EnvmapSource.options`.
    """

    def __call__(
        self, text: str, /, *, width: int, options: Mapping[str, str]
    ) -> EnvironmentMap | np.ndarray: ...


@runtime_checkable
class PhotoToEnvmap(Protocol):
    """`from_photo(rgb_srgb, *, fov_deg, width, options)`: the HDR light around a photo's camera.

    `rgb_srgb` is the photo as displayed, `[H, W, 3]` float32 sRGB in [0, 1]; `fov_deg` its horizontal
    field of view. The map is in the frame of a level camera looking along world +y (module docstring).
    """

    def __call__(
        self, rgb_srgb: np.ndarray, /, *, fov_deg: float, width: int, options: Mapping[str, str]
    ) -> EnvironmentMap | np.ndarray: ...


@dataclass(frozen=True, kw_only=True)
class EnvmapSource:
    """A lighting source: a name and at least one of `from_text` / `from_photo`.

    Attributes:
        name: the name users type (`--source NAME`); lower case, digits, `.`, `_`, `-`. It must equal
            the entry point's name.
        description: one line for `gaffer-envmap sources`.
        from_text: words -> world map (`TextToEnvmap`), or None.
        from_photo: photo -> map around its camera (`PhotoToEnvmap`), or None.
        options: the `KEY`s of `--source-option KEY=VALUE` the source takes (e.g. "weights" for a
            local checkpoint path); any other key is refused before the source runs.

    Raises:
        EnvmapSourceError: a bad name, no capability, or a capability that is not callable.
    """

    name: str
    description: str = ""
    from_text: TextToEnvmap | None = None
    from_photo: PhotoToEnvmap | None = None
    options: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not _NAME.match(self.name):
            raise EnvmapSourceError(
                f"`name` {self.name!r} is not a source name; use lower case letters, digits, '.', "
                "'_' and '-', starting with a letter or digit."
            )
        if self.from_text is None and self.from_photo is None:
            raise EnvmapSourceError(
                f"source {self.name!r} has neither `from_text` nor `from_photo`; give it at least one."
            )
        for what in ("from_text", "from_photo"):
            fn = getattr(self, what)
            if fn is not None and not callable(fn):
                raise EnvmapSourceError(
                    f"source {self.name!r}: `{what}` is a {type(fn).__name__}, not a callable."
                )
        object.__setattr__(self, "options", tuple(self.options))

    @property
    def capabilities(self) -> tuple[Capability, ...]:
        """`("text",)`, `("photo",)` or both, in that order."""
        found = (("text", self.from_text), ("photo", self.from_photo))
        return tuple(c for c, fn in found if fn is not None)  # type: ignore[misc]


@dataclass(frozen=True, kw_only=True)
class SourceEntry:
    """One registered source as found in the installed distributions (loaded, or why not).

    Attributes:
        name: the entry point's name.
        target: what it points at, `module:attribute`.
        distribution: the distribution that registers it, "name version" ("?" when unknown).
        source: the loaded `EnvmapSource`, or None when loading failed.
        error: why loading failed ("ImportError: ..."), or None.
    """

    name: str
    target: str
    distribution: str
    source: EnvmapSource | None = None
    error: str | None = None

    def describe(self) -> str:
        """One line for a person: name, capabilities, options, where it comes from."""
        if self.source is None:
            return (
                f"{self.name}: failed to load ({self.error}) [{self.distribution}: {self.target}]"
            )
        src = self.source
        what = "+".join(src.capabilities)
        opts = f"; options: {', '.join(src.options)}" if src.options else ""
        text = f" - {src.description}" if src.description else ""
        return f"{self.name} ({what}){text}{opts} [{self.distribution}]"


def _one_line(exc: BaseException) -> str:
    msg = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {msg}" if msg else type(exc).__name__


def _distribution(ep: importlib.metadata.EntryPoint) -> str:
    dist = getattr(ep, "dist", None)
    if dist is None:
        return "?"
    return f"{dist.metadata['Name']} {dist.version}"


def _load(ep: importlib.metadata.EntryPoint) -> EnvmapSource:
    obj = ep.load()
    if not isinstance(obj, EnvmapSource) and callable(obj):
        obj = obj()  # a factory: a plugin keeps its import cheap
    if not isinstance(obj, EnvmapSource):
        raise EnvmapSourceError(
            f"{ep.value} is a {type(obj).__name__}, not a gaffer_envmap.sources.EnvmapSource (or a "
            "callable returning one)"
        )
    if obj.name != ep.name:
        raise EnvmapSourceError(
            f"{ep.value} is named {obj.name!r} but registered as {ep.name!r}; make them equal"
        )
    return obj


def _entry_points() -> dict[str, list[importlib.metadata.EntryPoint]]:
    found: dict[str, list[importlib.metadata.EntryPoint]] = {}
    for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        same = found.setdefault(ep.name, [])
        if all(e.value != ep.value for e in same):  # one distribution seen twice on the path
            same.append(ep)
    return found


def _entry(name: str, eps: list[importlib.metadata.EntryPoint]) -> SourceEntry:
    ep = eps[0]
    if len(eps) > 1:
        others = ", ".join(f"{_distribution(e)} ({e.value})" for e in eps)
        return SourceEntry(
            name=name,
            target=ep.value,
            distribution=_distribution(ep),
            error=f"registered more than once: {others}; uninstall one",
        )
    try:
        source = _load(ep)
    except Exception as exc:  # a broken plugin is reported, never a crash of the list
        return SourceEntry(
            name=name, target=ep.value, distribution=_distribution(ep), error=_one_line(exc)
        )
    return SourceEntry(name=name, target=ep.value, distribution=_distribution(ep), source=source)


def envmap_sources() -> tuple[SourceEntry, ...]:
    """Every source registered under `ENTRY_POINT_GROUP`, sorted by name, each loaded.

    A plugin that fails to import or to build its `EnvmapSource` is listed with its error (never
    raised), so one broken plugin does not hide the others.

    Example:
        >>> "sky" in [e.name for e in envmap_sources()]
        True
    """
    return tuple(_entry(name, eps) for name, eps in sorted(_entry_points().items()))


def load_envmap_source(name: str, *, flag: str = "--source") -> EnvmapSource:
    """The source registered as `name`.

    Args:
        name: the entry point's name.
        flag: the command-line flag to name in errors.

    Raises:
        EnvmapSourceError: unknown name (the message lists the installed sources), or a plugin that
            failed to load (named, with its exception).
    """
    eps = _entry_points()
    if name not in eps:
        installed = ", ".join(sorted(eps)) or "none"
        hint = (
            " The built-in 'sky' is registered by gaffer-envmap's own entry point: reinstall it "
            "(pip install -e packages/gaffer-envmap)."
            if name == "sky"
            else " Install the plugin's package, or list them with `gaffer-envmap sources`."
        )
        raise EnvmapSourceError(
            f"`{flag}` {name!r} is not an installed lighting source (group "
            f"{ENTRY_POINT_GROUP}); installed: {installed}.{hint}"
        )
    entry = _entry(name, eps[name])
    if entry.source is None:
        raise EnvmapSourceError(
            f"`{flag}` {name!r} ({entry.target}, from {entry.distribution}) failed to load: "
            f"{entry.error}. Fix or reinstall that plugin."
        )
    return entry.source


def format_source_list(entries: tuple[SourceEntry, ...] | None = None) -> str:
    """The installed sources, one line each (what `gaffer-envmap sources` prints)."""
    entries = envmap_sources() if entries is None else entries
    if not entries:
        return f"no lighting sources installed (entry-point group {ENTRY_POINT_GROUP})"
    return "\n".join(e.describe() for e in entries)


def parse_source_options(
    pairs: list[str] | None, source: EnvmapSource | None, *, flag: str = "--source-option"
) -> dict[str, str]:
    """`KEY=VALUE` strings -> a dict, refusing a malformed pair or a key the source does not take.

    Example:
        >>> src = EnvmapSource(name="m", from_text=lambda t, *, width, options: np.ones((1, 2, 3)), options=("weights",))
        >>> parse_source_options(["weights=/models/m.safetensors"], src)
        {'weights': '/models/m.safetensors'}
    """
    options: dict[str, str] = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise EnvmapSourceError(f"`{flag}` {pair!r} is not KEY=VALUE (e.g. weights=/models/x).")
        if source is not None and key not in source.options:
            takes = ", ".join(source.options) or "no options"
            raise EnvmapSourceError(
                f"`{flag}` {key!r}: source {source.name!r} takes {takes}; drop it."
            )
        options[key] = value
    return options


def validate_source_map(
    result: object, *, source: str, width: int, policy: SanitizePolicy = "raise"
) -> EnvironmentMap:
    """Check and normalise what a source returned.

    Args:
        result: an `EnvironmentMap` or an array `[He, 2*He, 3]`.
        source: the source's name (for messages and the `gaffer:source` metadata key).
        width: the width asked for; a map of another 2:1 size is resampled (power-exact) to it.
        policy: NaN/Inf/negative handling (`gaffer_envmap.sanitize.SanitizePolicy`).

    Returns:
        A Blender-convention, pixel-centred `EnvironmentMap` `[width // 2, width, 3]` whose metadata
        has `gaffer:source` (and `gaffer:source_note` when it was resampled or converted).

    Raises:
        EnvmapSourceError: not a map, a wrong shape, or NaN/Inf/negative values the policy refuses.
    """
    who = f"source {source!r}"
    notes: list[str] = []
    if isinstance(result, EnvironmentMap):
        env = result
    elif isinstance(result, np.ndarray | list | tuple):
        arr = np.asarray(result)
        if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
            raise EnvmapSourceError(f"{who} returned a {arr.dtype} array; return float radiance.")
        if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[1] != 2 * arr.shape[0] or arr.size == 0:
            raise EnvmapSourceError(
                f"{who} returned an array of shape {arr.shape}; expected [He, 2*He, 3] (a 2:1 "
                "lat-long RGB map, linear radiance)."
            )
        env = None
    else:
        raise EnvmapSourceError(
            f"{who} returned a {type(result).__name__}; return a gaffer_envmap.EnvironmentMap or a "
            "[He, 2*He, 3] float array."
        )
    raw = env.radiance_linear if env is not None else np.asarray(result)
    try:
        clean, report = sanitize(raw, policy, name=f"the map of {who}")
    except NonFiniteError:
        _, found = sanitize(raw, "zero")
        raise EnvmapSourceError(
            f"{who} returned a map with {found.describe()} values (policy {policy!r}); fix the "
            "source: radiance must be finite and >= 0."
        ) from None
    if not report.clean:
        notes.append(f"{report.describe()} values repaired ({policy})")
    if env is None:
        env = EnvironmentMap(radiance_linear=clean)
    elif clean is not raw:
        env = env.with_radiance(clean)
    try:
        if env.alignment != "center":
            from gaffer_envmap.convention_transforms import to_center_alignment

            env = to_center_alignment(env)
            notes.append("resampled to pixel-centre alignment")
        if env.convention != "blender":
            from gaffer_envmap.convention_transforms import convert_convention

            notes.append(f"converted from the {env.convention} convention")
            env = convert_convention(env, "blender")
    except GafferError as exc:
        raise EnvmapSourceError(f"{who} returned a map gaffer cannot use: {exc}") from exc
    if env.width != width:
        from gaffer_envmap.resample import resize_conservative

        notes.append(f"resampled from {env.width}x{env.height} (power kept)")
        env = resize_conservative(env, width // 2)
    meta = {**env.metadata, "gaffer:source": source}
    if notes:
        meta["gaffer:source_note"] = "; ".join(notes)
    return EnvironmentMap(
        radiance_linear=env.radiance_linear,
        convention=env.convention,
        alignment=env.alignment,
        metadata=meta,
    )


def _run(source: EnvmapSource, what: Capability, call: Callable[[], object]) -> object:
    try:
        return call()
    except GafferError as exc:
        raise EnvmapSourceError(f"source {source.name!r} refused: {exc}") from exc
    except Exception as exc:  # the plugin's own failure, named: not a gaffer bug
        raise EnvmapSourceError(
            f"source {source.name!r} failed ({what}): {_one_line(exc)}. Check its options and "
            "weights (--debug shows the traceback)."
        ) from exc


def _require(source: EnvmapSource, what: Capability, flag: str) -> None:
    """Refuse, naming what the source can do, when it lacks `what`."""
    if what in source.capabilities:
        return
    has = " and ".join(source.capabilities)
    other = {"text": "a photo (gaffer-diffusion insert --light-source)", "photo": "words (--text)"}
    raise EnvmapSourceError(
        f"`{flag}` {source.name!r} cannot start from {'words' if what == 'text' else 'a photo'}: "
        f"it takes {has} only; use it with {other[source.capabilities[0]]}."
    )


def _check_width(width: int) -> None:
    if not isinstance(width, int) or width < 2 or width % 2:
        raise EnvmapSourceError(f"`width` is {width!r}; pass an even integer >= 2.")


def envmap_from_text(
    source: EnvmapSource,
    text: str,
    *,
    width: int,
    options: Mapping[str, str] | None = None,
    policy: SanitizePolicy = "raise",
    flag: str = "--source",
) -> EnvironmentMap:
    """Run a source's `from_text` and check what it returns (`validate_source_map`).

    Raises:
        EnvmapSourceError: the source has no `from_text`, failed, or returned a bad map.
    """
    _require(source, "text", flag)
    _check_width(width)
    fn = source.from_text
    if fn is None:  # _require refused it already; this narrows the type
        raise EnvmapSourceError(f"source {source.name!r} has no from_text.")
    opts = dict(options or {})
    result = _run(source, "text", lambda: fn(text, width=width, options=opts))
    return validate_source_map(result, source=source.name, width=width, policy=policy)


def envmap_from_photo(
    source: EnvmapSource,
    rgb_srgb: np.ndarray,
    *,
    fov_deg: float | int,
    width: int,
    options: Mapping[str, str] | None = None,
    policy: SanitizePolicy = "raise",
    flag: str = "--source",
) -> EnvironmentMap:
    """Run a source's `from_photo` on `[H, W, 3]` sRGB in [0, 1] and check what it returns.

    Raises:
        EnvmapSourceError: the source has no `from_photo`, failed, or returned a bad map.
    """
    _require(source, "photo", flag)
    _check_width(width)
    fn = source.from_photo
    if fn is None:  # _require refused it already; this narrows the type
        raise EnvmapSourceError(f"source {source.name!r} has no from_photo.")
    rgb = np.asarray(rgb_srgb, np.float32)
    opts = dict(options or {})
    result = _run(
        source, "photo", lambda: fn(rgb, fov_deg=float(fov_deg), width=width, options=opts)
    )
    return validate_source_map(result, source=source.name, width=width, policy=policy)
