"""Reading a ``.pt2`` (``torch.export.save``) archive without letting the file run code.

``torch.export.load`` is not a safe loader: it unpickles ``data/sample_inputs/*.pt`` with
``weights_only=False`` when the safe load fails, reads a weight or constant whose config says
``use_pickle`` with ``torch.load(weights_only=False)``, unpickles opaque constants, loads
AOTInductor's compiled libraries, and hands the program's text to code generators
(:mod:`.pt2_check`).  Here the archive is opened as a zip and only this is read:

* ``models/<name>.json``, checked by :func:`.pt2_check.check_program` before torch parses it;
* the weights and constants listed by their configs, as raw little-endian buffers (no pickle):
  an entry marked ``use_pickle``, a TorchBind or opaque object, or AOTInductor code is refused;
* nothing else: sample inputs and extra files are never opened.

Then torch's own deserialiser builds the program from those parts, and every operator the
resulting graphs call is checked once more as an object (:func:`.pt2_check.allowed_target`).
"""
from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any

from .pt2_check import ProgramRefused, allowed_target, check_program

__all__ = ["load_exported_program", "ProgramRefused", "MAX_PROGRAM_JSON_BYTES", "MAX_ARCHIVE_BYTES"]

MAX_PROGRAM_JSON_BYTES = 256 * 2**20
# Weights of a policy the harness drives on a CPU: far above any shipped model (a few MB).
MAX_ARCHIVE_BYTES = 8 * 2**30


def load_exported_program(path: Path) -> Any:
    """The ``torch.export.ExportedProgram`` saved at ``path``; raises :class:`ProgramRefused`
    (a ``ValueError``) saying what in the archive was refused, and why."""
    from torch._export.serde import schema
    from torch._export.serde.serialize import ExportedProgramDeserializer, _dict_to_dataclass

    try:
        archive = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError) as exc:
        raise ProgramRefused(f"not a .pt2 archive (a zip file): {exc}") from None
    with archive:
        files = _Files(archive)
        model = files.model_name()
        try:
            document = json.loads(files.read(f"models/{model}.json", MAX_PROGRAM_JSON_BYTES))
        except (ValueError, RecursionError) as exc:
            raise ProgramRefused(f"models/{model}.json is not JSON torch writes: {str(exc)[:200]}") from None
        try:
            program = check_program(document)
        except RecursionError:
            raise ProgramRefused(f"models/{model}.json nests deeper than any program torch writes") from None
        state_dict = _payloads(files, f"data/weights/{model}_weights_config.json", "data/weights/", weights=True)
        constants = _payloads(files, f"data/constants/{model}_constants_config.json", "data/constants/",
                              weights=False)
    try:
        serialized = _dict_to_dataclass(schema.ExportedProgram, program)
        exported = ExportedProgramDeserializer(None).deserialize(serialized, state_dict, constants, None)
    except RecursionError:
        raise ProgramRefused("its program nests deeper than torch's deserialiser can follow") from None
    _check_targets(exported.graph_module)
    return exported


class _Files:
    """The archive's members under its one root folder, read with a size bound."""

    def __init__(self, archive: zipfile.ZipFile):
        self.archive = archive
        infos = archive.infolist()
        roots = {info.filename.split("/", 1)[0] for info in infos}
        if len(roots) != 1 or not infos:
            raise ProgramRefused("a .pt2 archive holds one folder; this one holds "
                                 f"{len(roots)} at its top")
        self.root = roots.pop() + "/"
        self.infos = {info.filename[len(self.root):]: info for info in infos}
        if sum(info.file_size for info in infos) > MAX_ARCHIVE_BYTES:
            raise ProgramRefused(f"its members unpack to more than {MAX_ARCHIVE_BYTES >> 30} GiB")
        if any(name.startswith(("data/aotinductor/", "data/executorch/", "data/mtia")) for name in self.infos):
            raise ProgramRefused("it holds compiled code (AOTInductor, ExecuTorch or MTIA), which loads native "
                                 "libraries; save the model with torch.export.save, without compiling it")
        if self.text("archive_format") != "pt2":
            raise ProgramRefused("its archive_format is not 'pt2': not saved by torch.export.save "
                                 "(torch 2.6 or newer)")
        if self.text("archive_version") != "0":
            raise ProgramRefused(f"archive_version {self.text('archive_version')!r}: this loader reads version 0")
        if "byteorder" in self.infos and self.text("byteorder") != "little":
            raise ProgramRefused("its tensors are big-endian; save it on a little-endian machine")

    def model_name(self) -> str:
        models = sorted(name[len("models/"):-len(".json")] for name in self.infos
                        if name.startswith("models/") and name.endswith(".json"))
        if len(models) != 1:
            raise ProgramRefused(f"a model archive holds one program (models/<name>.json); this holds {len(models)}")
        return models[0]

    def has(self, name: str) -> bool:
        return name in self.infos

    def read(self, name: str, limit: int = MAX_ARCHIVE_BYTES) -> bytes:
        info = self.infos.get(name)
        if info is None:
            raise ProgramRefused(f"{name} is missing from the archive")
        if info.file_size > limit:
            raise ProgramRefused(f"{name} is {info.file_size} bytes, more than the {limit} this loader reads")
        try:
            return self.archive.read(info)
        except (zipfile.BadZipFile, OSError, EOFError, RuntimeError) as exc:
            raise ProgramRefused(f"{name} cannot be read: {exc}") from None

    def text(self, name: str) -> str:
        return self.read(name, 4096).decode("utf-8", "replace").strip()


def _payloads(files: _Files, config_name: str, folder: str, *, weights: bool) -> dict[str, Any]:
    """The tensors a weights or constants config lists, from their raw buffers; aliases
    (tied weights: one file, several views) share their storage as torch's loader does."""
    import torch
    from torch._export.serde import schema
    from torch._export.serde.serialize import (
        _dict_to_dataclass, deserialize_scalar_type, deserialize_size, deserialize_storage_offset,
        deserialize_stride)

    if not files.has(config_name):
        if files.has(f"{folder}{config_name.rsplit('/', 1)[1].split('_')[0]}.pt"):
            raise ProgramRefused(f"its {folder} are one pickle (the format before torch 2.6); "
                                 "save the model again with torch.export.save")
        raise ProgramRefused(f"{config_name} is missing from the archive")
    try:
        config = _dict_to_dataclass(schema.PayloadConfig, json.loads(files.read(config_name, 64 * 2**20)))
    except (ValueError, TypeError, KeyError, RecursionError) as exc:
        raise ProgramRefused(f"{config_name} is not a payload config torch writes: {str(exc)[:200]}") from None
    buffers: dict[str, Any] = {}
    out: dict[str, Any] = {}
    for fqn, meta in config.config.items():
        where = f"{config_name}: {fqn!r}"
        if meta.use_pickle:
            raise ProgramRefused(f"{where} is stored as a pickle (use_pickle), which loading would run")
        name = meta.path_name
        if not name.startswith("weight_" if weights else "tensor_"):
            raise ProgramRefused(f"{where} is stored as {name!r}: an object other than a tensor "
                                 "(TorchBind or opaque), which loading would unpickle")
        if meta.tensor_meta is None:
            raise ProgramRefused(f"{where} has no tensor_meta")
        tm = meta.tensor_meta
        try:
            dtype = deserialize_scalar_type(tm.dtype)
            size, stride = deserialize_size(tm.sizes), deserialize_stride(tm.strides)
            offset = deserialize_storage_offset(tm.storage_offset)
        except Exception as exc:  # noqa: BLE001 - a symbolic size or an unknown dtype in a weight
            raise ProgramRefused(f"{where} has a tensor_meta torch does not write for a weight: {exc}") from None
        if name not in buffers:
            raw = files.read(folder + name)
            itemsize = torch.empty((), dtype=dtype).element_size()
            if len(raw) % itemsize:
                raise ProgramRefused(f"{folder}{name} holds {len(raw)} bytes, not a whole number of {dtype}")
            buffers[name] = (torch.frombuffer(bytearray(raw), dtype=dtype) if raw
                             else torch.empty(0, dtype=dtype))
        try:
            tensor = torch.as_strided(buffers[name], size, stride, offset)
        except RuntimeError as exc:
            raise ProgramRefused(f"{where}: its shape {list(size)} does not fit {folder}{name}: {exc}") from None
        if meta.is_param:
            tensor = torch.nn.Parameter(tensor, requires_grad=tm.requires_grad)
        out[fqn] = tensor
    return out


def _check_targets(graph_module: Any) -> None:
    import torch

    for module in graph_module.modules():
        if not isinstance(module, torch.fx.GraphModule):
            continue
        for node in module.graph.nodes:
            if node.op == "call_method" or (node.op == "call_function" and not allowed_target(node.target)):
                raise ProgramRefused(f"node {node.name!r} calls {node.target!r}, which this loader does not run")
