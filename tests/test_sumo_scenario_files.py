"""The scenario's XML files (issue 43): written by an XML library, so that any folder or network path is escaped,
and a scenario.sumocfg that is not as sumo-demand wrote it (its manifest can be written again by whoever edits it)
is refused before SUMO runs: no outputs outside the scenario, no TraCI port."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from trafficgeo.errors import InputError
from trafficgeo.simulation.scenario import SumoScenario, _outputs_add, _sumocfg, check_sumocfg

HOSTILE = 'a "quoted" & <odd> folder'


def scenario(tmp: Path, net_rel: str) -> SumoScenario:
    folder = tmp / "scenario"
    folder.mkdir()
    (folder / "scenario.sumocfg").write_text(_sumocfg(net_rel, 900.0, 0.5, 7, 10.0))
    return SumoScenario(folder, tmp / "run", (folder / net_rel).resolve(), None, 900.0, 0.0, 600.0, 300.0, 0.5, 7)


def test_paths_with_quotes_ampersands_and_brackets_are_escaped(tmp_path: Path) -> None:
    add = ET.fromstring(_outputs_add(f"/x/{HOSTILE}/simulated.edgedata.xml", 900.0, 300.0, 900.0))
    assert add.find("edgeData").get("file") == f"/x/{HOSTILE}/simulated.edgedata.xml"
    cfg = ET.fromstring(_sumocfg(f"../{HOSTILE}/city.net.xml", 900.0, 0.5, 7, 10.0))
    assert cfg.find("input/net-file").get("value") == f"../{HOSTILE}/city.net.xml"
    assert cfg.find("time/end").get("value") == "900.000" and cfg.find("random_number/seed").get("value") == "7"


def test_the_scenario_as_written_is_accepted(tmp_path: Path) -> None:
    check_sumocfg(scenario(tmp_path, f"../{HOSTILE}/city.net.xml"))


EDITS = {
    "an output elsewhere": ("<output>", '<output>\n        <summary-output value="/tmp/elsewhere.xml"/>'),
    "a TraCI port": ("</configuration>", '<traci_server><remote-port value="8813"/></traci_server></configuration>'),
    "another route file": ('value="demand.rou.xml"', 'value="/home/someone/other.rou.xml"'),
    "another fcd output": ('<fcd-output value="fcd.xml"', '<fcd-output value="/etc/fcd.xml"'),
    "another network": ('value="city.net.xml"', 'value="../other.net.xml"'),
}


@pytest.mark.parametrize("edit", sorted(EDITS))
def test_an_edited_sumocfg_is_refused(edit: str, tmp_path: Path) -> None:
    sc = scenario(tmp_path, "city.net.xml")
    old, new = EDITS[edit]
    text = sc.sumocfg.read_text()
    assert old in text
    sc.sumocfg.write_text(text.replace(old, new, 1))
    with pytest.raises(InputError, match="not as 'trafficgeo sumo-demand' wrote it"):
        check_sumocfg(sc)
