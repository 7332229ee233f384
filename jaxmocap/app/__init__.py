"""Application layer: whole pipelines from a lab's files to results on disk.

Each module here chains the library's readers, methods and writers for one job and is
what a command-line verb calls (`jaxmocap.cli` stays thin glue). Nothing in the library
proper imports from here.
"""
