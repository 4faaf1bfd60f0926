"""The evaluation view: an evaluation folder's report table (report.md's, else one made from
results.json, as `lmjx evaluate` writes it: `lmjx.view.trialrecord.results_records`) and a
list of its trials, each opened as a trial view (replayed on its failure's map, in its
scene) in the same page."""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from lmjx.errors import LmjxError
from lmjx.mapfile.read import MapFile, load_map
from lmjx.view.legend import Page
from lmjx.view.replay import Replay, frame_at, replay
from lmjx.view.trial import ROOT, TrialView
from lmjx.view.trialrecord import TrialRecord, from_dict, map_for, results_records


def report_table(folder: Path, records: list[dict]) -> str:
    """The first markdown table of the folder's report.md, else a summary of the records."""
    report = folder / "report.md"
    if report.is_file():
        lines = report.read_text(encoding="utf-8", errors="replace").splitlines()
        start = next((i for i, line in enumerate(lines) if line.startswith("|")), None)
        if start is not None:
            end = next((i for i in range(start, len(lines)) if not lines[i].startswith("|")), len(lines))
            return "\n".join(lines[start:end])
    from lmjx.evaluation.evaluate import summarize

    rows = ["| failure | scenario | ASM | trials | success |", "| --- | --- | --- | ---: | ---: |"]
    for r in summarize(records):
        rows.append(f"| {r['failure']} | {r['scenario']} | {r['asm']} | {r['trials']} | "
                    f"{100 * r['success_rate']:.1f} % |")  # fmt: skip
    return "\n".join(rows)


def trial_label(r: dict) -> str:
    ok = "success" if r.get("success") else "failure"
    return f"{r['failure']}/{r['scenario']}/{r['asm']}/{r['seed']}: {ok}, {r.get('actions', '?')} actions"


class EvaluationView:
    """An evaluation folder's table and trials; `open(key)` replays and shows one."""

    def __init__(
        self, server: Any, folder: Path, maps: list[str] | None, say: Callable[[str], None] | None = None
    ) -> None:
        self.server = server
        self.folder = folder
        self.records = results_records(folder / "results.json")
        self.maps = maps
        self.say = say
        self.opened: dict[str, MapFile] = {}
        self.trial: TrialView | None = None
        self.folder_handle: Any = None
        self.lock = threading.Lock()
        gui = server.gui
        gui.add_markdown(f"**Evaluation {folder}**: {len(self.records)} trials")
        with gui.add_folder("Report", expand_by_default=False):
            gui.add_markdown(report_table(folder, self.records))
        labels = {trial_label(r): r for r in self.records if "failure" in r and "seed" in r}
        self.by_label = labels
        self.choice = gui.add_dropdown("Trial", tuple(labels) or ("(none)",))
        button = gui.add_button("Open this trial", disabled=not labels)
        self.status = gui.add_markdown("")
        button.on_click(lambda _: threading.Thread(target=self._open_chosen, daemon=True).start())

    def _open_chosen(self) -> None:
        r = self.by_label.get(self.choice.value)
        if r is not None:
            try:
                self.open(from_dict(r, str(self.folder / "results.json")))
            except LmjxError as e:
                self.status.content = f"Cannot open it: {e}"

    def map_file(self, record: TrialRecord) -> MapFile:
        if record.failure not in self.opened:
            self.opened[record.failure] = load_map(map_for(record, self.maps), lazy=True)
        return self.opened[record.failure]

    def open(self, record: TrialRecord, at: str = "start") -> TrialView:
        """Replay trial `record` and show it (in place of the one shown)."""
        with self.lock:
            self.status.content = f"Replaying {record.key} ..."
            m = self.map_file(record)
            assert m.robot is not None
            view = self.show(replay(m.robot, m, record, say=self.say), at)
            self.status.content = ""
            return view

    def show(self, rep: Replay, at: str = "start") -> TrialView:
        """Show a replayed trial (in place of the one shown)."""
        if self.folder_handle is not None:
            self.folder_handle.remove()
        self.server.scene.remove_by_name(ROOT)
        self.folder_handle = self.server.gui.add_folder(f"Trial {rep.record.key}")
        with self.folder_handle:
            self.trial = TrialView(self.server, rep, at=frame_at(at, len(rep.frames)))
        return self.trial

    @property
    def page(self) -> Page:
        """The shown trial's page (its title and legend), else the evaluation's."""
        if self.trial is not None:
            return self.trial.page
        return Page(f"Evaluation {self.folder}", (f"{len(self.records)} trials; open one with --trial F/S/ASM/SEED",))

    def tick(self) -> None:
        if self.trial is not None:
            self.trial.tick()

    def close(self) -> None:
        for m in self.opened.values():
            m.close()
