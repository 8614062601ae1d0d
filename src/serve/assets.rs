//! The page, its script and its styles, built into the binary
//! (`assets/serve/`): plain HTML, CSS and JavaScript with no build step,
//! nothing fetched from elsewhere.

/// The file `name` and its media type.
pub fn get(name: &str) -> Option<(&'static str, &'static str)> {
    match name {
        "index.html" => Some((
            include_str!("../../assets/serve/index.html"),
            "text/html; charset=utf-8",
        )),
        "app.js" => Some((
            include_str!("../../assets/serve/app.js"),
            "text/javascript; charset=utf-8",
        )),
        "style.css" => Some((
            include_str!("../../assets/serve/style.css"),
            "text/css; charset=utf-8",
        )),
        _ => None,
    }
}
