//! Terrain features that strokes are matched to: the visible silhouettes of a
//! view and the ridge lines of the terrain (section 5.1 of Tassé et al.).
