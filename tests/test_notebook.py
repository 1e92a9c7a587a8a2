"""notebooks/fault_trace_analysis.ipynb runs from a clean kernel and shows the fault sample's faults.

The notebook is committed with its outputs (so it reads well where notebooks are rendered); this test
executes it again in a fresh kernel, from notebooks/ as Jupyter would and its first cells from the
repository root, and checks the outputs that matter. To refresh the committed outputs after a change:

    python tests/test_notebook.py
"""

from __future__ import annotations

import base64
import copy
import os
import re
import sys
import tempfile
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

REPO = Path(__file__).resolve().parents[1]
NOTEBOOK = REPO / "notebooks" / "fault_trace_analysis.ipynb"
VERDICTS = {"ok": 53, "nak": 7, "timeout": 0, "pnio_error": 2, "reference_mismatch": 0, "malformed": 0}


def execute(nb: nbformat.NotebookNode, cwd: Path) -> nbformat.NotebookNode:
    """Run every cell in a new kernel (IPC transport: no TCP port), stopping at the first error."""
    from jupyter_client.manager import KernelManager

    with tempfile.TemporaryDirectory(prefix="pd-nb-") as sockets:
        km = KernelManager(kernel_name="python3", transport="ipc", ip=os.path.join(sockets, "kernel"))
        client = NotebookClient(nb, km=km, timeout=120, record_timing=False, resources={"metadata": {"path": str(cwd)}})
        client.execute()
    return nb


def text_of(cell: nbformat.NotebookNode) -> str:
    return "".join(o.get("text", "") + o.get("data", {}).get("text/plain", "") for o in cell.outputs)


def cell_with(nb: nbformat.NotebookNode, source: str) -> nbformat.NotebookNode:
    return next(c for c in nb.cells if c.cell_type == "code" and c.source.startswith(source))


def pngs(nb: nbformat.NotebookNode) -> list[bytes]:
    return [base64.b64decode(o.data["image/png"]) for c in nb.cells if c.cell_type == "code"
            for o in c.outputs if "image/png" in o.get("data", {})]


@pytest.fixture(scope="module")
def executed() -> nbformat.NotebookNode:
    nb = nbformat.read(NOTEBOOK, as_version=4)
    for cell in nb.cells:
        if cell.cell_type == "code":
            cell.outputs, cell.execution_count = [], None
    return execute(nb, NOTEBOOK.parent)


def counts(text: str) -> dict[str, int]:
    return {v: int(n) for v, n in re.findall(r"^(\w+)\s+(\d+)$", text, re.M)}


def test_notebook_runs_from_a_clean_kernel(executed: nbformat.NotebookNode) -> None:
    errors = [o for c in executed.cells if c.cell_type == "code" for o in c.outputs if o.output_type == "error"]
    assert not errors
    code = [c for c in executed.cells if c.cell_type == "code"]
    assert [c.execution_count for c in code] == list(range(1, len(code) + 1))
    assert "../sample_pcaps/fault_trace.pcap" in text_of(code[0])  # found from notebooks/


def test_notebook_shows_the_faults(executed: nbformat.NotebookNode) -> None:
    assert counts(text_of(cell_with(executed, "a.transactions.verdict.value_counts()"))) == VERDICTS
    naks = text_of(cell_with(executed, "p = a.parameters"))
    for line in ("P1300[0] 0x11", "P1121[0] 0x02", "P9999[0] 0x00", "P2[0]    0x01", "P1120[0] 0x05"):
        assert line in naks
    failed = text_of(cell_with(executed, "t = a.transactions"))
    assert "DF80B100" in failed and "DE80B500" in failed and "deadline" in failed
    latency = text_of(cell_with(executed, "done = t[t.t_total.notna()]"))
    assert re.search(r"192\.168\.1\.22\s+93\.7", latency)  # the slow drive
    assert "P971[0]          12" in text_of(cell_with(executed, 't.nlargest(5, "b5_retries")'))
    changes = text_of(cell_with(executed, 'a.changes[["t"'))
    assert "error 0x02: low or high limit exceeded" in changes and "pnio_error" in changes
    drill = text_of(cell_with(executed, "f.loc[f.name.isin("))
    assert drill.count("ndr.status.code1") == 4 and drill.count("0xb5") == 3
    images = pngs(executed)
    assert len(images) == 5 and all(i[:8] == b"\x89PNG\r\n\x1a\n" and len(i) > 10_000 for i in images)


def test_notebook_shows_the_parameter_state_and_the_intended_set(executed: nbformat.NotebookNode) -> None:
    state = text_of(cell_with(executed, "s = a.parameter_state"))
    for param in ("P1121[0]", "P2[0]", "P1300[0]", "P1120[0]"):
        assert param in state
    assert "operating state" in state and "393" in state
    audit = text_of(cell_with(executed, "import tempfile"))
    assert audit.startswith("0 findings with the set") and audit.count("expect_mismatch") == 1


def test_committed_notebook_has_current_outputs(executed: nbformat.NotebookNode) -> None:
    committed = nbformat.read(NOTEBOOK, as_version=4)
    code = [c for c in committed.cells if c.cell_type == "code"]
    assert all(c.outputs for c in code), "commit the notebook with its outputs (python tests/test_notebook.py)"
    assert [c.execution_count for c in code] == list(range(1, len(code) + 1))
    assert len(pngs(committed)) == 5
    for source in ("a.transactions.verdict.value_counts()", "p = a.parameters", "a.changes[[",
                   "s = a.parameter_state"):
        assert text_of(cell_with(committed, source)) == text_of(cell_with(executed, source)), source


def test_finds_the_sample_from_the_repository_root() -> None:
    nb = nbformat.read(NOTEBOOK, as_version=4)
    first = [c for c in nb.cells if c.cell_type == "code"][:2]
    for c in first:
        c.outputs = []
    small = copy.deepcopy(nb)
    small.cells = first
    out = execute(small, REPO)
    assert "sample_pcaps/fault_trace.pcap" in text_of(out.cells[0]) and "../" not in text_of(out.cells[0])
    assert counts(text_of(out.cells[1])) == VERDICTS


def test_readme_recipes_run() -> None:
    """The README's notebook recipes answer their questions on the fault sample."""
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    block = re.search(r"### Notebook recipes.*?```python\n(.*?)```", readme, re.S).group(1)
    lines = [line for line in block.splitlines() if line.strip()]
    assert len(lines) == 5
    code = block.replace('"trace.pcapng"', repr(str(REPO / "sample_pcaps" / "fault_trace.pcap")))
    namespace: dict = {}
    results = []
    for line in code.splitlines():
        statement = line.split("  #")[0].strip()
        if statement.startswith(("import", "a = ")):
            exec(statement, namespace)
        elif statement:
            results.append(eval(statement, namespace))
    failed, slow, changes = results
    assert len(failed) == 6 and failed.loc[("192.168.1.22", "P1300[0]", "0x11")].item() == 2
    assert slow.index[0] == "192.168.1.22"
    assert len(changes) == 12 and list(changes.columns)[-1] == "result"


def main() -> int:
    """Execute the notebook from a clean kernel and save it with its outputs."""
    nb = nbformat.read(NOTEBOOK, as_version=4)
    for cell in nb.cells:
        cell.metadata.pop("execution", None)
    nb = execute(nb, NOTEBOOK.parent)
    nbformat.validate(nb)
    nbformat.write(nb, NOTEBOOK)
    print(f"executed and saved {NOTEBOOK.relative_to(REPO)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
