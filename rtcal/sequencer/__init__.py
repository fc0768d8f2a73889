"""What every plan shares about the machines: the checks of each motion and reading against the
command (:mod:`.checks`), the ISO 230-2 approach (:mod:`.motion`) and the operator's steps (:mod:`.operator`)."""
