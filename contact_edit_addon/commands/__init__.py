"""The ``contact-edit`` command (:mod:`.cli`) and what its subcommands run: batch posing of saved scenes
(:mod:`.batch`), the embedded demo (:mod:`.demo`), the extension build (:mod:`.build`) and the add-on's
two benchmarks (:mod:`.operator_benchmark`, :mod:`.rig_benchmark`).

The command must start without Blender, so this package imports nothing: :mod:`.cli` imports ``bpy``
(through the other modules here) only for the subcommands that need it.
"""
