//! Sketches: the strokes a user draws over a first-person view, their depth
//! order (T-junctions) and their matching to terrain features (sections 4, 5
//! and 7 of Tassé et al., Computers & Graphics 2014).
