//! One path field for every page: a text field (typing a path always
//! works) with a **Browse…** button that opens the platform's native file
//! or folder dialog ([`rfd`]); and the labelled single-line text field it
//! is made of ([`labelled_line`]), for the pages' other text fields.
//!
//! On Linux `rfd` is built with its `xdg-portal` back end only: it talks to
//! the desktop's file-chooser portal through `libdbus-1`, loaded at run
//! time, and falls back to `zenity`; nothing is linked at build time, so
//! `cargo run --release` and `cargo test --workspace` need no GTK or other
//! development package (the `gtk3` back end would). Where neither a portal
//! nor zenity is available the dialog reports nothing and the page says to
//! type the path.
//!
//! The dialog blocks the thread that opens it, so it runs on a thread of
//! its own and the field polls its answer each frame: the GUI keeps
//! drawing and draining the engine's telemetry meanwhile (on macOS, whose
//! dialogs must run on the main thread, it is opened in the frame).

use std::path::{Path, PathBuf};
use std::sync::mpsc::{self, Receiver, TryRecvError};

/// What the field names.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PathKind {
    /// An existing file to open, with a filter (name, extensions).
    Open(&'static str, &'static [&'static str]),
    /// A file to save, with a filter (name, extensions).
    Save(&'static str, &'static [&'static str]),
    /// A folder (existing or to be made inside the chosen one).
    Folder,
}

/// Filter of TOML files (rig files, calibrations, protocols).
pub const TOML: (&str, &[&str]) = ("TOML", &["toml"]);

/// A path field's state between frames: the dialog in flight, if any.
#[derive(Debug, Default)]
pub struct PathField {
    pending: Option<Receiver<Option<PathBuf>>>,
    /// The last dialog failed or was unavailable.
    unavailable: bool,
}

/// What happened to a path field this frame.
#[derive(Debug)]
pub struct PathFieldResponse {
    /// The text field.
    pub edit: egui::Response,
    /// The user chose a path in the dialog (the text now holds it).
    pub picked: bool,
    /// Enter was pressed in the field.
    pub submitted: bool,
}

impl PathField {
    /// Draw `text` as a single-line field of `width` points with `hint`,
    /// labelled `label` (accessibility), and a Browse… button.
    pub fn ui(
        &mut self,
        ui: &mut egui::Ui,
        label: &str,
        text: &mut String,
        kind: PathKind,
        hint: &str,
        width: f32,
    ) -> PathFieldResponse {
        let picked = self.poll(text);
        let edit = labelled_line(ui, label, text, hint, width);
        let submitted = edit.lost_focus() && ui.input(|i| i.key_pressed(egui::Key::Enter));
        let busy = self.pending.is_some();
        let b = ui
            .add_enabled(!busy, egui::Button::new("Browse…"))
            .on_hover_text(match kind {
                PathKind::Folder => "choose the folder in a file dialog",
                PathKind::Open(..) => "choose the file in a file dialog",
                PathKind::Save(..) => "choose where to save in a file dialog",
            });
        if b.clicked() {
            self.open(kind, text.trim(), ui.ctx());
        }
        if busy {
            ui.spinner();
            ui.ctx()
                .request_repaint_after(std::time::Duration::from_millis(100));
        }
        if self.unavailable {
            ui.weak("no file dialog on this system: type the path");
        }
        PathFieldResponse {
            edit,
            picked,
            submitted,
        }
    }

    /// Is a dialog open?
    pub fn is_open(&self) -> bool {
        self.pending.is_some()
    }

    fn poll(&mut self, text: &mut String) -> bool {
        let Some(rx) = &self.pending else {
            return false;
        };
        match rx.try_recv() {
            Err(TryRecvError::Empty) => false,
            Err(TryRecvError::Disconnected) => {
                self.pending = None;
                self.unavailable = true;
                false
            }
            Ok(choice) => {
                self.pending = None;
                match choice {
                    Some(p) => {
                        *text = p.display().to_string();
                        true
                    }
                    None => false,
                }
            }
        }
    }

    fn open(&mut self, kind: PathKind, current: &str, ctx: &egui::Context) {
        self.unavailable = false;
        let start = start_dir(current);
        let (tx, rx) = mpsc::channel();
        let ctx = ctx.clone();
        let run = move || {
            let mut d = rfd::FileDialog::new();
            if let Some(dir) = &start {
                d = d.set_directory(dir);
            }
            let choice = match kind {
                PathKind::Folder => d.pick_folder(),
                PathKind::Open(name, ext) => d.add_filter(name, ext).pick_file(),
                PathKind::Save(name, ext) => d.add_filter(name, ext).save_file(),
            };
            let _ = tx.send(choice);
            ctx.request_repaint();
        };
        if cfg!(target_os = "macos") {
            run();
        } else if std::thread::Builder::new()
            .name("kilotouch-file-dialog".into())
            .spawn(run)
            .is_err()
        {
            self.unavailable = true;
            return;
        }
        self.pending = Some(rx);
    }
}

/// The folder a dialog opens in: the typed path's folder if it exists.
fn start_dir(current: &str) -> Option<PathBuf> {
    if current.is_empty() {
        return None;
    }
    let p = Path::new(current);
    let dir = if p.is_dir() { Some(p) } else { p.parent() };
    dir.filter(|d| d.is_dir()).map(Path::to_path_buf)
}

/// `label`, then `text` as a single-line field of `width` points with
/// `hint`, labelled by `label` (accessibility); the field's response.
pub fn labelled_line(
    ui: &mut egui::Ui,
    label: &str,
    text: &mut String,
    hint: &str,
    width: f32,
) -> egui::Response {
    let l = ui.label(label);
    ui.add(
        egui::TextEdit::singleline(text)
            .hint_text(hint)
            .desired_width(width),
    )
    .labelled_by(l.id)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dialogs_open_where_the_typed_path_is() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path().display().to_string();
        assert_eq!(start_dir(&d).as_deref(), Some(dir.path()));
        let f = dir.path().join("cal.toml").display().to_string();
        assert_eq!(start_dir(&f).as_deref(), Some(dir.path()));
        assert_eq!(start_dir(""), None);
        assert_eq!(start_dir("/no/such/folder/x.toml"), None);
    }
}
