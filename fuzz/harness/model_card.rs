//! The pose model card (`*.card.json`), then the graph it names (a missing or foreign
//! file: the hash check refuses it).

/// One input; errors are fine, panics, aborts and hangs are the bugs.
pub fn run(data: &[u8]) {
    let path = crate::scratch::file("model.card.json", data);
    if let Ok(card) = tricons::pose::card::ModelCard::read(&path) {
        let _ = card.preprocess_config();
        let _ = card.read_verified_graph(&path);
    }
}
