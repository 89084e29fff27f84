"""The ``rigslim`` command line: :mod:`~rigslim.commands.cli` (the parser and ``main``) and one module per command.

``run``, ``report``, ``plugins``, ``batch``, ``reduce``, ``lod``, ``compare`` and ``inspect``
(:mod:`~rigslim.commands.gltf_common`: what the four glTF front ends share). Each command only parses
its options and calls the layers below (docs/layout.md).
"""
