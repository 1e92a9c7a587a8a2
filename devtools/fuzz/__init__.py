"""Mutation fuzzing of the whole pipeline, seeded from every capture of sample_pcaps/ and ../shared/captures/.

`python -m devtools.fuzz --help` gives the command line (devtools/fuzz/__main__.py).

A *case* is a window of up to 40 consecutive frames of one seed capture, each frame mutated with high
probability (bit flips, byte insertions and deletions, truncation at every layer, length and count
fields set to 0, 1, max and max-1, fragment and sequence numbers scrambled, link types and timestamps
changed), sometimes followed by a fragment or request flood. Every frame of a case goes through the
dump path (`Dissector(annotate=True)`, the check marks, the text and JSON renderers) and the report path
(`Dissector(annotate=False)`, `TransactionEngine`, table rows); every few cases the seed *file* itself is
mutated (record and block lengths, magic, gzip stream, truncation at every record) and read with
`capture.frames`, and one in 32 of those files goes through `analyze()`, the summary, the CSV files and
the HTML report. What counts as a failure:

- crash: any exception (for a mutated file: any exception but `CaptureError`);
- hang: one frame (or one file) taking longer than `--frame-limit` seconds (a SIGALRM interrupts it);
- invariant: frames read != decoded + skipped + malformed, or frames read != frames fed;
- bounds: a field of a frame whose offset and length do not lie inside the frame, or whose raw bytes
  are not the frame's bytes there;
- inert output: a control character in the text dump, or a JSON line that is not ASCII JSON.

Cases are numbered and generated from `--seed` and their number alone, so any case replays exactly.

Modules: corpus (the seed captures and the offsets of their decoded fields), mutators (frame, case
and file mutations), harness (Runner: a case through the dump and report paths, a mutated file
through the reader and analyze(); the checks that count as failures), campaign (chunks of cases
over worker processes, replay of one case, the report text), __main__ (the command line).
"""
