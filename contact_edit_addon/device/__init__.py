"""Driving an armature live from the modular puppet device (Glauser et al. 2016), or from its simulator.

* :mod:`.session` — a live device driving one armature, ticked on the main thread.
* :mod:`.bridge` — the armature's bones, shape keys and properties as the numbers the device drives.
* :mod:`.properties` — what the scene keeps (``scene.contact_edit_device``): the port, the bindings, the kit.
* :mod:`.operators` — connect, bind, calibrate, identify, key, stop and propose a device for a kit.
* :mod:`.panel` — the *Puppet Device* sub-panel of the Contact tab.
"""
