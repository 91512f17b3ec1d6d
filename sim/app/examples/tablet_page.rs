//! Serves the tablet page alone and prints the button presses (to try it from a tablet or look
//! at it): `cargo run -p stylet-app --example tablet_page -- [ADDR]` (default 127.0.0.1:8765).

fn main() {
    let addr = std::env::args().nth(1).unwrap_or_else(|| "127.0.0.1:8765".into());
    let Ok(addr) = addr.parse() else {
        eprintln!("{addr}: not an address such as 0.0.0.0:8765");
        std::process::exit(2);
    };
    let (tx, rx) = std::sync::mpsc::channel();
    let page = match stylet_app::tablet::TabletPage::start(addr, tx) {
        Ok(p) => p,
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(1);
        }
    };
    println!("tablet page on http://{}, pairing code {}", page.addr, page.code());
    for cmd in rx {
        println!("{cmd:?}");
    }
}
