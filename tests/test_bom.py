"""A TOML file that starts with a UTF-8 byte-order mark (as Windows editors write it) is
read as the same file without one: it used to fail with "Invalid statement (at line 1,
column 1)"."""

import pkmctl
from pkmctl.campaign import CampaignSpec

BOM = "\ufeff"
SCENARIO = 'name = "bom"\n[timing]\nduration = 0.01\n'
SPEC = 'scenario = "base.toml"\ncontrollers = ["pd", "fsmc"]\nseeds = 1\nduration = 0.01\n'


def test_a_scenario_file_with_a_bom_is_the_file_without(tmp_path):
    plain, marked = tmp_path / "plain.toml", tmp_path / "bom.toml"
    plain.write_text(SCENARIO, encoding="utf-8")
    marked.write_text(BOM + SCENARIO, encoding="utf-8")
    assert marked.read_bytes().startswith(b"\xef\xbb\xbf")
    sc = pkmctl.Scenario.from_toml(marked)
    assert sc == pkmctl.Scenario.from_toml(plain) and sc.name == "bom"
    assert pkmctl.Scenario.from_toml(BOM + SCENARIO) == sc  # the text, read by the caller


def test_a_campaign_spec_with_a_bom_is_read_and_stored_without_it(tmp_path):
    """Its base scenario file too. The BOM is no part of the spec's text: a spec with one
    hashes as the same text without (``spec_text_sha256``), so a campaign folder's own
    ``spec.toml``, saved again with a BOM, is still read with the folder's stored inputs."""
    from pkmctl.campaign.store import open_store, read_spec, stored_inputs

    for name, text in (("base.toml", SCENARIO), ("c.toml", SPEC)):
        (tmp_path / name).write_text(text, encoding="utf-8")
        (tmp_path / f"bom-{name}").write_text(BOM + text, encoding="utf-8")
    marked = tmp_path / "bom-c.toml"
    marked.write_text(BOM + SPEC.replace("base.toml", "bom-base.toml"), encoding="utf-8")
    spec = CampaignSpec.from_toml(marked)
    plain = CampaignSpec.from_toml(tmp_path / "c.toml")
    assert spec.digest == plain.digest and spec.base.name == "bom"
    assert not spec.text.startswith(BOM)
    out = tmp_path / "camp"
    open_store(out, spec, resume=False)
    stored = out / "spec.toml"
    assert not stored.read_bytes().startswith(b"\xef\xbb\xbf")
    stored.write_text(BOM + stored.read_text(encoding="utf-8"), encoding="utf-8")
    assert read_spec(out).digest == spec.digest
    again = CampaignSpec.from_toml(stored)
    assert again.digest == spec.digest
    assert stored_inputs(out, again.text) is not None  # read with the folder's own copies
    text = BOM + SPEC.replace("base.toml", str(tmp_path / "base.toml"))
    assert CampaignSpec.from_toml(text).digest == spec.digest  # the text, read by the caller
