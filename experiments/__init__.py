"""Investigations that are not part of the installed stack: one folder per question (experiments/<name>/), each with
the command that writes its page and record under docs/results/ and its own tests. They import the msfsu_* packages;
no msfsu_* package imports them."""
