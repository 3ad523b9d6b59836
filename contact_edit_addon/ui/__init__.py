"""What the add-on shows and how it is reached: the sidebar's Contact tab (:mod:`.panels`), the
viewport overlay of patches, axes, previews and the brush (:mod:`.overlays`), and the tools' hotkeys
(:mod:`.keymaps`). The puppet device's sub-panel is in :mod:`..device.panel`."""
