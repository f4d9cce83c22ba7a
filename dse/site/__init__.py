"""The static report site of an output root (`dse site`): see build.py and docs/site.md."""
