//! The service's HTTP request-head framing and parsing.

use tricons::output::http::{BadRequest, MAX_REQUEST_BYTES, head_complete, parse_request};

/// One input; errors are fine, panics, aborts and hangs are the bugs.
pub fn run(data: &[u8]) {
    let _ = head_complete(data);
    match parse_request(data) {
        Ok(_) => {
            // Only a GET request line within the size limit routes anywhere.
            assert!(data.len() <= MAX_REQUEST_BYTES);
            let text = String::from_utf8_lossy(data);
            assert_eq!(text.lines().next().and_then(|l| l.split_whitespace().next()), Some("GET"));
        }
        Err(BadRequest::TooLarge) => assert!(data.len() > MAX_REQUEST_BYTES),
        Err(_) => {}
    }
}
