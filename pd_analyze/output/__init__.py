"""The outputs: the dump (text, JSON), decoded hex blocks, the report files and their summary, plots and
the HTML report."""
