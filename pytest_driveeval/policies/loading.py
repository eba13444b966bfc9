"""Loading a model (policy) from a spec string, safely by default.

Spec forms:
  ``model.pt2``                  exported program (``torch.export.save``; policies.export), as shipped;
                                 read by .pt2_archive, which unpickles nothing and runs only ATen
  ``model.pt``                   TorchScript archive (``torch.jit.save``), deprecated by torch but loaded
  ``weights.pt=pkg.mod:factory`` state_dict loaded with ``weights_only=True`` into ``factory()``
  ``pkg.mod:factory``            whatever ``factory()`` returns (a module or any callable)
  ``pickle:model.pt``            a whole pickled model: runs code from the file, so only
                                 when the user asks for it by this name
"""
from __future__ import annotations

import importlib
import re
import warnings
import zipfile
from pathlib import Path
from typing import Any, Callable

from ..core.errors import ModelError
from .fx_forward import fast_forward
from .planner_api import is_planner
from .pt2_archive import ProgramRefused, load_exported_program

PICKLE_PREFIX = "pickle:"
ALLOW_CODE_OPTION = "--driveeval-allow-scenario-code"
ALLOW_CODE_INI = "driveeval_allow_scenario_code"


# 'package.module:factory': dotted names either side of one colon.
_FACTORY = re.compile(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)*:[A-Za-z_]\w*(\.[A-Za-z_]\w*)*")
# What a model file ends in, so that 'models:v2.pt2' stays a file name.
_MODEL_SUFFIXES = frozenset({".pt2", ".pt", ".pth", ".ts", ".jit", ".zip", ".bin", ".ckpt"})


def names_factory(spec: str) -> bool:
    """Whether ``spec`` alone names a factory to import and call ('package.module:make_model')
    rather than a model file."""
    spec = spec.strip()
    return bool(_FACTORY.fullmatch(spec)) and Path(spec).suffix.lower() not in _MODEL_SUFFIXES


def runs_code(spec: str) -> bool:
    """Whether loading ``spec`` imports and calls Python named by the spec, or
    unpickles (which can call anything).  TorchScript and exported programs
    run only their own graph, and baseline names are ours."""
    spec = spec.strip()
    if spec.startswith(PICKLE_PREFIX) or "=" in spec:
        return True
    return names_factory(spec)


def refuse_code_from_data(spec: str, where: str) -> None:
    """Scenario files travel with datasets; what they name must not run code
    unless the person running pytest said so."""
    raise ModelError(
        f"{where}: Model '{spec}' would run Python code named by the scenario file "
        f"({'unpickling' if spec.strip().startswith(PICKLE_PREFIX) else 'importing and calling a factory'}). "
        f"If you trust this file, run with {ALLOW_CODE_OPTION} (ini: {ALLOW_CODE_INI} = true); "
        "or give the model with --driveeval-model or a driveeval_model fixture in conftest.py, "
        "or save it as an exported program (torch.export.save, .pt2), which loads without running Python")


def import_object(target: str) -> Any:
    module_name, _, attr = target.partition(":")
    if not module_name or not attr:
        raise ModelError(f"'{target}' is not of the form 'package.module:name'")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ModelError(f"cannot import '{module_name}' for model '{target}': {exc}") from None
    obj = module
    for part in attr.split("."):
        if not hasattr(obj, part):
            raise ModelError(f"'{module_name}' has no attribute '{attr}' (model '{target}')")
        obj = getattr(obj, part)
    return obj


def _is_torchscript(path: Path) -> bool:
    # TorchScript archives carry their code; a plain state_dict archive does not.
    try:
        with zipfile.ZipFile(path) as archive:
            return any("/code/" in name for name in archive.namelist())
    except zipfile.BadZipFile:
        return False


def _resolve(path: str, base: Path | None) -> Path:
    candidate = Path(path).expanduser()
    if not candidate.is_absolute() and base is not None:
        candidate = base / candidate
    try:
        if candidate.is_dir():
            raise ModelError(f"model {candidate} is a folder; give the model file inside it")
        if not candidate.is_file():
            raise ModelError(f"model file not found: {candidate}")
    except OSError as exc:  # a symlink loop, a name too long
        raise ModelError(f"cannot open model {candidate}: {exc.strerror or exc}") from None
    return candidate


def _call_factory(target: str) -> Any:
    factory = import_object(target)
    if not callable(factory):
        raise ModelError(f"'{target}' is a {type(factory).__name__}, not a factory to call")
    try:
        model = factory()
    except TypeError as exc:
        raise ModelError(f"cannot call {target}() without arguments to build the model: {exc}") from None
    if not callable(model) and not is_planner(model):
        raise ModelError(f"{target}() returned a {type(model).__name__}, not a model (a torch module or callable, "
                         "or a planner with initialize and plan: policies.planner_api)")
    return model


def load_model(spec: str, base: Path | None = None) -> Callable[..., Any]:
    """Load the model a spec names; relative paths resolve against ``base``."""
    import torch

    spec = spec.strip()
    if spec.startswith(PICKLE_PREFIX):
        path = _resolve(spec[len(PICKLE_PREFIX):], base)
        try:
            model = torch.load(path, map_location="cpu", weights_only=False)
        except Exception as exc:  # noqa: BLE001 - any unpickling failure is the file's fault
            raise ModelError(f"cannot unpickle model {path}: {exc}") from None
        return _eval(model)
    weights, sep, factory = spec.partition("=")
    if sep:
        path = _resolve(weights, base)
        module = _call_factory(factory)
        try:
            state = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as exc:  # noqa: BLE001
            raise ModelError(f"cannot read weights {path} (loaded with weights_only=True): {exc}") from None
        if isinstance(state, dict) and "state_dict" in state and isinstance(state["state_dict"], dict):
            state = state["state_dict"]
        try:
            module.load_state_dict(state)
        except (RuntimeError, TypeError, AttributeError) as exc:
            raise ModelError(f"weights {path} do not fit {factory}(): {exc}") from None
        return _eval(module)
    if names_factory(spec):
        return _eval(_call_factory(spec))
    path = _resolve(spec, base)
    if path.suffix == ".pt2":
        # Never torch.export.load: it unpickles parts of the archive (see .pt2_archive).
        try:
            return ExportedModel(load_exported_program(path).module())
        except ProgramRefused as exc:
            raise ModelError(f"refused exported program {path}: {exc}. An archive that torch.export.save "
                             "wrote from a model of ATen operators loads; this one would run code "
                             "from the file") from None
        except Exception as exc:  # noqa: BLE001
            raise ModelError(f"cannot load exported program {path}: {exc}") from None
    if not _is_torchscript(path):
        raise ModelError(
            f"{path} is not a TorchScript archive. For a state_dict give 'weights.pt=package.module:factory'; "
            f"a whole pickled model loads only as '{PICKLE_PREFIX}{path}' (it runs code from the file)")
    try:
        with warnings.catch_warnings():
            # torch deprecates TorchScript; the file is the user's choice, and it loads as it did.
            warnings.filterwarnings("ignore", r".*torch\.jit\.load.* is deprecated", DeprecationWarning)
            return _eval(torch.jit.load(str(path), map_location="cpu"))
    except Exception as exc:  # noqa: BLE001
        raise ModelError(f"cannot load TorchScript model {path}: {exc}") from None


class ExportedModel:
    """An exported program's module that checks the shapes of its inputs once per shape.

    The module's hooks compare every call's input shapes with the program's
    constraints in Python (about 0.5 ms, a third of the GNN actor's call on one
    episode), though a policy is called with the same shape step after step.
    Tensors of a shape that passed go straight to the program's forward (as
    :func:`~.fx_forward.fast_forward` generates it, bit for bit the module's);
    anything else (a new shape, keyword or non-tensor arguments) goes through
    the hooks as before.  Everything else is the module's (``training``,
    ``state_dict`` ...).

    A dict of tensors (the planning model's input) is checked once per key
    order and shapes too: the hooks' check of it (pytree paths compared as
    sympy expressions) was half of a closed-loop unroll's time.  Such a call
    goes to the module's own generated forward, which flattens the dict by the
    program's input spec as the module does, without the hooks."""

    def __init__(self, module: Any):
        self.module = module
        self._passed: set[tuple] = set()
        self._forward: Callable[..., Any] | None = None

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        shapes = _shapes(args) if not kwargs else None
        if shapes is not None and shapes in self._passed:
            if any(type(a) is dict for a in args):
                return self.module.forward(*args)
            if self._forward is None:
                # The module's generated forward, with a quarter less Python per call (see .fx_forward).
                self._forward = fast_forward(self.module) or self.module.forward
            return self._forward(*args)
        out = self.module(*args, **kwargs)
        if shapes is not None:
            self._passed.add(shapes)
        return out

    def __getattr__(self, name: str) -> Any:
        if name in ("module", "_passed", "_forward"):  # not set yet (unpickling): no recursion
            raise AttributeError(name)
        return getattr(self.module, name)


def _shapes(args: tuple) -> tuple | None:
    """What the module's hooks check of ``args``, for tensors and dicts of tensors keyed by strings
    (a dict's keys in order: its pytree structure); None for anything else."""
    import torch

    def tensor(a: Any) -> tuple:
        return tuple(a.shape), a.dtype, a.device

    out = []
    for a in args:
        if type(a) is torch.Tensor:
            out.append(tensor(a))
        elif type(a) is dict and all(type(k) is str and type(v) is torch.Tensor for k, v in a.items()):
            out.append(("dict", tuple((k, tensor(v)) for k, v in a.items())))
        else:
            return None
    return tuple(out)


def model_files(spec: str, base: Path | None = None) -> tuple[Path, ...]:
    """The files :func:`load_model` reads for ``spec`` (none for a factory alone, whose module
    Python imports once per process anyway); raises ModelError as loading would for a missing one."""
    spec = spec.strip()
    if spec.startswith(PICKLE_PREFIX):
        return (_resolve(spec[len(PICKLE_PREFIX):], base),)
    weights, sep, _ = spec.partition("=")
    if sep:
        return (_resolve(weights, base),)
    if names_factory(spec):
        return ()
    return (_resolve(spec, base),)


def _eval(model: Any) -> Any:
    if hasattr(model, "eval"):
        model.eval()
    return model
