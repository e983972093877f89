"""A plugin imported twice (Dask's ``--preload FILE.py`` imports it, then reloads a copy)."""

import importlib
import importlib.util
import sys
import uuid

import pytest

from pkmctl.parts import PartError, get_part
from tests.test_campaign_plugins import LAW  # a controller named NAME


def _module(folder, module, name, source=LAW):
    path = folder / f"{module}.py"
    path.write_text(source.replace("NAME", name))
    return path


def test_the_same_file_of_the_same_text_registers_its_part_again(tmp_path, monkeypatch):
    module = "law_" + uuid.uuid4().hex[:10]
    name = module.replace("_", "-")
    path = _module(tmp_path, module, name)
    monkeypatch.syspath_prepend(str(tmp_path))
    mod = importlib.import_module(module)
    try:
        first = get_part("controller", name)
        assert first.functions["step"] is mod.law
        mod = importlib.reload(mod)  # as Dask's --preload of a .py file: no error
        again = get_part("controller", name)
        assert again is not first and again.functions["step"] is mod.law
        assert again.params is mod.P
        path.write_text(path.read_text().replace("GAIN = 1.0e4", "GAIN = 2.0e4"))
        with pytest.raises(PartError, match=rf"controller '{name}': a controller of that name "
                           rf"is already registered \(by {path}\)"):  # fmt: skip
            importlib.reload(mod)  # another text: refused
        other = tmp_path / "other"
        other.mkdir()
        copy = _module(other, module + "_b", name)  # the same text in another module
        loader = importlib.util.spec_from_file_location(module + "_b", copy)
        with pytest.raises(PartError, match=f"controller '{name}': a controller of that name"):
            loader.loader.exec_module(importlib.util.module_from_spec(loader))
        assert get_part("controller", name) is again
        # a copy of the module's file, of its text when registered, imported as the module
        # (Dask copies a --preload file to the worker's folder, and reloads that)
        path.write_text(path.read_text().replace("GAIN = 2.0e4", "GAIN = 1.0e4"))
        copy = _module(other, module, name)
        loader = importlib.util.spec_from_file_location(module, copy)
        loader.loader.exec_module(importlib.util.module_from_spec(loader))
        assert get_part("controller", name).functions["step"].__code__.co_filename == str(copy)
    finally:
        sys.modules.pop(module, None)
