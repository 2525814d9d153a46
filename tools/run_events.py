"""RUN/events.jsonl, the learner's record for programs (docs/guides/monitoring.md lists its events)."""
import json
import os


def read(run, kind=None):
    """The events of a run, of one kind or all, in order; [] where the run has no events.jsonl.
    A line that is not a JSON object (a run killed mid-write) is skipped."""
    out = []
    try:
        with open(os.path.join(run, "events.jsonl")) as f:
            for line in f:
                try:
                    e = json.loads(line)
                except ValueError:
                    continue
                if isinstance(e, dict) and (kind is None or e.get("event") == kind):
                    out.append(e)
    except OSError:
        pass
    return out
