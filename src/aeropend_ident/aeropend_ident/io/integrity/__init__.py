"""Whether a recording holds what it should: message loss counted while recording and checked when
a bag is read (:mod:`.loss`)."""
