"""The JNR face rig: template head, 52 joints, linear blend skinning. Knows nothing of the other packages."""
