"""`python -m pd_analyze.cli`: the same as the `pd-analyze` command."""

from pd_analyze.cli import main

main()
