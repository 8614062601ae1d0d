//! GeoJSON export (placeholder).
