"""Users' plugins: the one place mcrt runs a user's code.

A plugin is a Python file that registers samplers (and integrands for ``mcrt integrate``,
:func:`mcrt.register_integrand`) when it runs::

    # my_sampler.py
    import mcrt

    def jittered(count, n, rng):        # count sets of n points in [0, 1)^2
        ...
    mcrt.register_sampler("mine", points=jittered)

and is loaded with ``mcrt --plugin my_sampler.py ...`` (any command; the option may be
repeated), ``$MCRT_PLUGINS`` (paths separated by ``os.pathsep``), a study's ``plugins =
["my_sampler.py"]`` or :func:`load_plugin` from Python. Installed packages bring samplers
with an entry point in the group ``mcrt.samplers`` (:data:`ENTRY_POINT_GROUP`): its object
is a module (importing it registers) or a callable (called with no arguments)::

    [project.entry-points."mcrt.samplers"]
    mine = "my_package.samplers"             # or "my_package:register"

Entry points and ``$MCRT_PLUGINS`` are loaded by the command line before the
command runs, and in Python on the first sampler name mcrt does not know
(:func:`autoload`); ``import mcrt`` itself loads nothing.

A file is executed once per process (by its resolved path) as a module named
:func:`module_name` (in ``sys.modules``, so what it defines pickles by
reference where the same plugin is loaded). Mitsuba binds a Python sampler
class to the variant active when it was defined: after a variant switch,
``mcrt.register()`` runs each plugin again, re-creating its classes.

Dask workers (``--cluster``) load the same plugin files and entry points
before they build a sampler, and get the generators of samplers registered
in the client with ``register_sampler(points=...)`` (see :func:`worker_state`).

Every failure is a one-line :class:`PluginError` that names the file and
the line.
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import importlib.util
import logging
import os
import pickle
import re
import sys
import traceback
import types
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from .errors import SamplerError
from .samplers import registry

log = logging.getLogger("mcrt.plugins")

#: Environment variable listing plugin files (separated by ``os.pathsep``).
ENV = "MCRT_PLUGINS"
#: Entry-point group of installed packages' samplers.
ENTRY_POINT_GROUP = "mcrt.samplers"
#: The command-line option that loads a plugin file.
OPTION = "--plugin"

#: Loaded plugin files (resolved) and their modules, in load order.
_LOADED: dict[Path, types.ModuleType] = {}
#: The sampler names each loaded file registered.
_NAMES: dict[Path, tuple[str, ...]] = {}
#: The variant each file was last executed in (its classes derive from it).
_VARIANTS: dict[Path, str] = {}
#: SHA-256 of the bytes each loaded file ran (what a worker must run too).
_DIGESTS: dict[Path, str] = {}
#: Entry points loaded (by ``name = value``) and the names each registered.
_ENTRY_POINTS: dict[str, tuple[str, ...]] = {}
#: Whether this process has looked for entry points.
_entry_points_loaded = False
#: Names this process cannot build, with why (Dask workers: what the client
#: registered but could not send, plugins that failed to load here).
_UNAVAILABLE: dict[str, str] = {}
#: Plugin files a worker failed to load, with the error.
_FAILED: dict[str, str] = {}


class PluginError(SamplerError):
    """A plugin cannot be loaded: missing file, syntax error, an exception in
    its code, a sampler name that is taken. One line, naming the file and line."""

    def __init__(self, message: str) -> None:
        super().__init__(" ".join(str(message).split()))


# --------------------------------------------------------------------------- files


def module_name(path: str | os.PathLike[str]) -> str:
    """The module name a plugin file runs as: ``mcrt_plugin_<stem>_<hash of the path>``
    (the same in every process that loads the same file)."""
    resolved = Path(path).expanduser().resolve()
    stem = re.sub(r"\W", "_", resolved.stem) or "plugin"
    digest = hashlib.sha256(str(resolved).encode()).hexdigest()[:10]
    return f"mcrt_plugin_{stem}_{digest}"


def _resolve(path: str | os.PathLike[str]) -> Path:
    try:
        resolved = Path(path).expanduser().resolve()
        found = resolved.is_file()
        directory = not found and resolved.is_dir()
    except (OSError, RuntimeError, ValueError) as error:
        raise PluginError(f"plugin {path}: {getattr(error, 'strerror', None) or error}") from None
    if directory:
        raise PluginError(f"plugin {path}: is a directory; give the plugin's .py file")
    if not found:
        raise PluginError(f"plugin {path}: no such file")
    return resolved


def load_plugin(path: str | os.PathLike[str], quiet: bool = False) -> types.ModuleType:
    """Run the plugin file ``path`` (once per process: a file loaded already is not run
    again) and return its module; a one-line :class:`PluginError` if it cannot be read or
    fails. A note if it registered nothing, unless ``quiet`` (read for its functions)."""
    resolved = _resolve(path)
    if resolved in _LOADED:
        return _LOADED[resolved]
    module = _execute(resolved)
    if not _NAMES[resolved] and not quiet:
        log.warning("plugin %s registered no sampler or integrand (call mcrt.register_sampler "
                    "or mcrt.register_integrand in it)", resolved)
    return module


def load_plugins(paths: Iterable[str | os.PathLike[str]]) -> list[Path]:
    """Load each plugin file of ``paths`` (in order); their resolved paths."""
    paths = list(paths)
    for path in paths:
        load_plugin(path)
    return [_resolve(path) for path in paths]


def loaded_plugins() -> list[Path]:
    """The plugin files loaded in this process (resolved paths), in load order."""
    return list(_LOADED)


def plugin_names(path: str | os.PathLike[str]) -> tuple[str, ...]:
    """The names the loaded plugin ``path`` registered (an integrand's: ``integrand NAME``)."""
    return _NAMES.get(Path(path).expanduser().resolve(), ())


def unload_plugin(path: str | os.PathLike[str]) -> None:
    """Forget a loaded plugin: its samplers and integrands are unregistered and its
    module removed, so :func:`load_plugin` runs the (edited) file again."""
    resolved = Path(path).expanduser().resolve()
    if resolved not in _LOADED:
        return
    for name in _NAMES.pop(resolved, ()):
        if name in registry.names() and registry.info(name).origin == str(resolved):
            registry.unregister(name)
    registry.forget(str(resolved))
    del _LOADED[resolved]
    _VARIANTS.pop(resolved, None)
    _DIGESTS.pop(resolved, None)
    sys.modules.pop(module_name(resolved), None)


def _execute(path: Path) -> types.ModuleType:
    """Run ``path`` as a fresh module (registrations default to it, see
    :func:`mcrt.samplers.registry.registering`)."""
    import mitsuba as mi

    try:
        source = path.read_bytes()
    except OSError as error:
        raise PluginError(f"plugin {path}: cannot read it ({error.strerror})") from None
    try:
        code = compile(source, str(path), "exec", dont_inherit=True)
    except SyntaxError as error:
        raise PluginError(f"plugin {path}, line {error.lineno}: {type(error).__name__}: "
                          f"{error.msg}") from None
    except ValueError as error:  # e.g. a NUL byte
        raise PluginError(f"plugin {path}: not Python source ({error})") from None
    name = module_name(path)
    module = types.ModuleType(name)
    module.__file__ = str(path)
    module.__spec__ = importlib.util.spec_from_loader(name, loader=None, origin=str(path))
    previous = sys.modules.get(name)
    sys.modules[name] = module
    try:
        with registry.registering(str(path), functools.partial(_rebuild, path)) as names:
            try:
                exec(code, module.__dict__)  # noqa: S102 - running the user's plugin is the point
            except (Exception, SystemExit) as error:
                for registered in dict.fromkeys(n for n in names if n in registry.names()):
                    if registry.info(registered).kind in ("user", "points"):
                        registry.unregister(registered)
                registry.forget(str(path))
                raise PluginError(_failure(f"plugin {path}", error, str(path))) from None
    except BaseException:
        if previous is not None:
            sys.modules[name] = previous
        else:
            sys.modules.pop(name, None)
        raise
    _LOADED[path] = module
    _NAMES[path] = tuple(dict.fromkeys(names))
    _VARIANTS[path] = mi.variant() or ""
    _DIGESTS[path] = hashlib.sha256(source).hexdigest()
    return module


def _rebuild(path: Path) -> None:
    """After a variant switch (``mcrt.register()``): run the plugin again, so its
    classes derive from the new variant's ``mi.Sampler``."""
    import mitsuba as mi

    if path in _LOADED and _VARIANTS.get(path) != mi.variant():
        _execute(path)


def _failure(what: str, error: BaseException, file: str | None = None) -> str:
    """``WHAT, line N: Type: message`` for an exception raised by a user's code:
    the line is the last one of ``file`` in its traceback (else of the last
    frame outside mcrt and importlib)."""
    frames = traceback.extract_tb(error.__traceback__)
    ours = str(Path(__file__).resolve().parent)
    line = next((f for f in reversed(frames) if file is not None and f.filename == file), None)
    if line is None:
        line = next((f for f in reversed(frames) if not f.filename.startswith((ours, "<"))
                     and "importlib" not in f.filename), None)
    where = ""
    if line is not None:
        where = f", line {line.lineno}" if line.filename == file else \
            f" ({line.filename}, line {line.lineno})"
    message = str(error) if isinstance(error, SamplerError) else \
        f"{type(error).__name__}: {error}".rstrip(": ")
    return f"{what}{where}: {message}"


# --------------------------------------------------------------------------- environment


def from_environment() -> list[Path]:
    """Load the plugin files ``$MCRT_PLUGINS`` lists (``os.pathsep``-separated)."""
    text = os.environ.get(ENV, "")
    paths = [p.strip() for p in text.split(os.pathsep) if p.strip()]
    try:
        return load_plugins(paths)
    except PluginError as error:
        raise PluginError(f"{error} (from ${ENV})") from None


def load_entry_points() -> list[str]:
    """Load the installed packages' samplers (entry-point group
    ``mcrt.samplers``), once per process; the names they registered."""
    global _entry_points_loaded
    if _entry_points_loaded:
        return [n for names in _ENTRY_POINTS.values() for n in names]
    _entry_points_loaded = True
    from importlib.metadata import entry_points

    seen = set()
    for entry in entry_points(group=ENTRY_POINT_GROUP):
        key = f"{entry.name} = {entry.value}"
        if key not in seen:
            seen.add(key)
            _ENTRY_POINTS[key] = _load_entry_point(entry)
    return [n for names in _ENTRY_POINTS.values() for n in names]


def _entry_origin(entry: Any) -> str:
    dist = getattr(entry, "dist", None)
    package = f" of {dist.name}" if dist is not None else ""
    return f"entry point {entry.name} = {entry.value}{package}"


def _load_entry_point(entry: Any, reload: bool = False) -> tuple[str, ...]:
    """Import an entry point's object (a module registers as it is imported; a
    callable is called) with its registrations attributed to it."""
    origin = _entry_origin(entry)
    with registry.registering(origin, functools.partial(_rebuild_entry_point, entry)) as names:
        try:
            if reload and entry.module in sys.modules:
                importlib.reload(sys.modules[entry.module])
            target = entry.load()
            if not isinstance(target, types.ModuleType):
                if not callable(target):
                    raise PluginError(f"{origin}: names {type(target).__name__} object, "
                                      f"not a module or a function")
                target()
        except PluginError:
            raise
        except (Exception, SystemExit) as error:
            file = _module_file(entry.module)
            raise PluginError(_failure(origin, error, file)) from None
    return tuple(dict.fromkeys(names))


def _module_file(module: str) -> str | None:
    try:
        spec = importlib.util.find_spec(module)
    except (ImportError, ValueError):
        return None
    return spec.origin if spec is not None else None


def _rebuild_entry_point(entry: Any) -> None:
    """After a variant switch: import the entry point's module again and call
    its callable again, re-creating the classes it defines."""
    key = f"{entry.name} = {entry.value}"
    _ENTRY_POINTS[key] = _load_entry_point(entry, reload=True)


def autoload() -> None:
    """Load the installed packages' samplers (once per process) and the files
    of ``$MCRT_PLUGINS`` (those not loaded yet): called by the command line before
    a command, and on the first sampler name mcrt does not know."""
    load_entry_points()
    from_environment()


def command_words(paths: Iterable[str | os.PathLike[str]]) -> list[str]:
    """``--plugin PATH`` for each path: what a recorded command line needs to load
    the same plugins (absolute paths, so it runs from any directory)."""
    return [w for p in paths for w in (OPTION, str(Path(p).expanduser().resolve()))]


def file_digest(path: str | os.PathLike[str]) -> str:
    """SHA-256 of a plugin file's bytes (recorded with a study: another version
    of the plugin is another sampler)."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return ""


# --------------------------------------------------------------------------- workers


def unavailable(name: str) -> str:
    """Why sampler ``name`` is missing in this process, if mcrt knows ("" if not):
    on a Dask worker, the client's sampler that could not be sent here, or a
    plugin that failed to load here."""
    if name in _UNAVAILABLE:
        return _UNAVAILABLE[name]
    if _FAILED:
        failed = "; ".join(_FAILED.values())
        return f"unknown sampler {name!r} on this worker, where a plugin failed to load: {failed}"
    return ""


def _plugin_registered() -> set[str]:
    return {n for names in _NAMES.values() for n in names} | \
        {n for names in _ENTRY_POINTS.values() for n in names}


def state_key() -> tuple:
    """Changes whenever :func:`worker_state` would (cheap: no pickling)."""
    users = tuple((n, registry.info(n).origin, id(_class_or_none(n)))
                  for n in registry.names() if registry.info(n).kind in ("user", "points"))
    return tuple((p, _DIGESTS.get(p, "")) for p in _LOADED), _entry_points_loaded, users


def _class_or_none(name: str) -> type | None:
    try:
        return registry.current_class(name)
    except KeyError:
        return None


def worker_state() -> dict[str, Any]:
    """What a Dask worker needs to know the samplers this process knows:

    * the plugin files loaded here, with their code's digests (a worker loads the same
      files: it must see them at the same paths, as with a shared file system);
    * whether the entry points were loaded (a worker loads its own);
    * every sampler registered here without a plugin file: a generator
      (``register_sampler(points=fn)``, sent by value with cloudpickle), a point
      file (its path) or a class from an importable module (its name); what
      cannot be sent gets a message telling the user to use a plugin file.

    :func:`install_worker_state` applies it on the worker.
    """
    from_plugins = _plugin_registered()
    shipped: list[tuple[str, bytes]] = []
    missing: dict[str, str] = {}
    for name in registry.names():
        entry = registry.info(name)
        if entry.kind not in ("user", "points") or name in from_plugins:
            continue
        try:
            shipped.append((name, _ship(name, entry.kind)))
        except Exception as error:  # noqa: BLE001 - any failure to pickle is reported as such
            missing[name] = (
                f"sampler {name!r} was registered in the client ({entry.origin}) and cannot "
                f"be sent to the Dask workers ({type(error).__name__}: "
                f"{' '.join(str(error).split())}); put its mcrt.register_sampler call in a "
                f"plugin file and load it with --plugin FILE.py (or plugins = [...] in a "
                f"study, or mcrt.plugins.load_plugin)")
    return {"files": {str(p): _DIGESTS[p] for p in _LOADED}, "entry_points": _entry_points_loaded,
            "shipped": shipped, "unavailable": missing}


def _ship(name: str, kind: str) -> bytes:
    """A registration to repeat on a worker, pickled (see :func:`worker_state`)."""
    import cloudpickle  # type: ignore[import-untyped]  # (a dependency of distributed)

    cls = registry.current_class(name)
    if kind == "points":
        source = cls.source  # type: ignore[attr-defined]
        options = {"randomize": cls.default_randomize,  # type: ignore[attr-defined]
                   "claims": tuple(getattr(cls, "claims", ())),
                   "origin": registry.info(name).origin}
        fn = getattr(source, "fn", None)
        if fn is None:  # a point file: its path
            return pickle.dumps(("file", name, str(source.path), options))
        options.update(sets=source.sets, seed=source.seed)
        module = _module_of(fn)
        by_value = module is not None and not module.__name__.startswith("mcrt.")
        if by_value:
            cloudpickle.register_pickle_by_value(module)
        try:
            return cloudpickle.dumps(("points", name, fn, options))
        finally:
            if by_value:
                cloudpickle.unregister_pickle_by_value(module)
    user = next((c for c in cls.__mro__ if c.__module__ != registry.__name__), cls)
    module_name_ = user.__module__
    if module_name_ == "__main__" or module_name_ not in sys.modules or \
            getattr(sys.modules[module_name_], "__file__", None) is None:
        raise PluginError(f"its class {user.__qualname__} is defined in {module_name_}, "
                          f"which a worker cannot import")
    return pickle.dumps(("class", name, module_name_, user.__qualname__,
                         registry.info(name).origin))


def _module_of(fn: Any) -> types.ModuleType | None:
    while isinstance(fn, functools.partial):
        fn = fn.func
    module = sys.modules.get(getattr(fn, "__module__", "") or "")
    return module if module is not None and module.__name__ != "builtins" else None


def install_worker_state(state: dict[str, Any]) -> None:
    """On a Dask worker (after ``mcrt.register()``): load the client's plugin
    files and entry points and repeat its other registrations. Never raises:
    what fails is recorded, and the error shows when a task asks for a sampler
    it lacks (:func:`unavailable`). A file loaded by an earlier command (workers
    outlive commands) whose code is not the client's runs again; other code than the
    client ran (a file edited since) is unloaded, never run."""
    for file, want in dict(state.get("files", {})).items():
        try:
            if want and _DIGESTS.get(_resolve(file), want) != want:
                unload_plugin(file)  # an older version: run the file again
            load_plugin(file)
            if want and (have := _DIGESTS[_resolve(file)]) != want:
                unload_plugin(file)
                raise PluginError(f"plugin {file} on this worker is not the code the client "
                                  f"loaded (sha256 {have[:12]}, the client's {want[:12]}): "
                                  f"edited since, or another copy; workers must see the same file")
            _FAILED.pop(file, None)
        except SamplerError as error:
            _FAILED[file] = str(error)
    if state.get("entry_points"):
        try:
            load_entry_points()
        except SamplerError as error:
            _FAILED["entry points"] = str(error)
    for name, payload in state.get("shipped", ()):
        try:
            _register_shipped(pickle.loads(payload))
            _UNAVAILABLE.pop(name, None)
        except Exception as error:  # noqa: BLE001 - reported when the sampler is asked for
            _UNAVAILABLE[name] = (f"sampler {name!r}, registered in the client, cannot be "
                                  f"registered on this worker ({type(error).__name__}: "
                                  f"{' '.join(str(error).split())}); put its "
                                  f"mcrt.register_sampler call in a plugin file and load it "
                                  f"with --plugin FILE.py")
    _UNAVAILABLE.update(state.get("unavailable", {}))


def _register_shipped(spec: tuple) -> None:
    from .samplers import register_sampler

    kind, name = spec[:2]
    if kind == "points":
        register_sampler(name, points=spec[2], **spec[3])
    elif kind == "file":
        register_sampler(name, file=spec[2], **spec[3])
    else:
        module = importlib.import_module(spec[2])
        cls: Any = module
        for part in spec[3].split("."):
            cls = getattr(cls, part)
        registry.register_class(cls, name, origin=spec[4])
