"""``python -m pipeline.accessory``: the follow figures (:func:`pipeline.accessory.follow.main`)."""

from pipeline.accessory.follow import main

main()
