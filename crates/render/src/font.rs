//! A tiny embedded 5x7 bitmap font (upper-case letters, digits, a little punctuation), drawn by
//! hand for labels; lower-case letters are drawn as upper case, unknown characters as a box.

/// Glyph width in pixels.
pub const GLYPH_W: usize = 5;
/// Glyph height in pixels.
pub const GLYPH_H: usize = 7;
/// Horizontal advance per character (glyph plus one pixel of spacing).
pub const ADVANCE: usize = GLYPH_W + 1;

/// The 7 rows of a glyph, 5 bits each (bit 4 = leftmost pixel).
pub fn glyph(c: char) -> [u8; 7] {
    let rows: [&str; 7] = match c.to_ascii_uppercase() {
        'A' => [
            ".###.", "#...#", "#...#", "#####", "#...#", "#...#", "#...#",
        ],
        'B' => [
            "####.", "#...#", "#...#", "####.", "#...#", "#...#", "####.",
        ],
        'C' => [
            ".###.", "#...#", "#....", "#....", "#....", "#...#", ".###.",
        ],
        'D' => [
            "####.", "#...#", "#...#", "#...#", "#...#", "#...#", "####.",
        ],
        'E' => [
            "#####", "#....", "#....", "####.", "#....", "#....", "#####",
        ],
        'F' => [
            "#####", "#....", "#....", "####.", "#....", "#....", "#....",
        ],
        'G' => [
            ".###.", "#...#", "#....", "#.###", "#...#", "#...#", ".####",
        ],
        'H' => [
            "#...#", "#...#", "#...#", "#####", "#...#", "#...#", "#...#",
        ],
        'I' => [
            ".###.", "..#..", "..#..", "..#..", "..#..", "..#..", ".###.",
        ],
        'J' => [
            "..###", "...#.", "...#.", "...#.", "...#.", "#..#.", ".##..",
        ],
        'K' => [
            "#...#", "#..#.", "#.#..", "##...", "#.#..", "#..#.", "#...#",
        ],
        'L' => [
            "#....", "#....", "#....", "#....", "#....", "#....", "#####",
        ],
        'M' => [
            "#...#", "##.##", "#.#.#", "#.#.#", "#...#", "#...#", "#...#",
        ],
        'N' => [
            "#...#", "#...#", "##..#", "#.#.#", "#..##", "#...#", "#...#",
        ],
        'O' => [
            ".###.", "#...#", "#...#", "#...#", "#...#", "#...#", ".###.",
        ],
        'P' => [
            "####.", "#...#", "#...#", "####.", "#....", "#....", "#....",
        ],
        'Q' => [
            ".###.", "#...#", "#...#", "#...#", "#.#.#", "#..#.", ".##.#",
        ],
        'R' => [
            "####.", "#...#", "#...#", "####.", "#.#..", "#..#.", "#...#",
        ],
        'S' => [
            ".####", "#....", "#....", ".###.", "....#", "....#", "####.",
        ],
        'T' => [
            "#####", "..#..", "..#..", "..#..", "..#..", "..#..", "..#..",
        ],
        'U' => [
            "#...#", "#...#", "#...#", "#...#", "#...#", "#...#", ".###.",
        ],
        'V' => [
            "#...#", "#...#", "#...#", "#...#", "#...#", ".#.#.", "..#..",
        ],
        'W' => [
            "#...#", "#...#", "#...#", "#.#.#", "#.#.#", "#.#.#", ".#.#.",
        ],
        'X' => [
            "#...#", "#...#", ".#.#.", "..#..", ".#.#.", "#...#", "#...#",
        ],
        'Y' => [
            "#...#", "#...#", ".#.#.", "..#..", "..#..", "..#..", "..#..",
        ],
        'Z' => [
            "#####", "....#", "...#.", "..#..", ".#...", "#....", "#####",
        ],
        '0' => [
            ".###.", "#...#", "#..##", "#.#.#", "##..#", "#...#", ".###.",
        ],
        '1' => [
            "..#..", ".##..", "..#..", "..#..", "..#..", "..#..", ".###.",
        ],
        '2' => [
            ".###.", "#...#", "....#", "...#.", "..#..", ".#...", "#####",
        ],
        '3' => [
            "#####", "...#.", "..#..", "...#.", "....#", "#...#", ".###.",
        ],
        '4' => [
            "...#.", "..##.", ".#.#.", "#..#.", "#####", "...#.", "...#.",
        ],
        '5' => [
            "#####", "#....", "####.", "....#", "....#", "#...#", ".###.",
        ],
        '6' => [
            "..##.", ".#...", "#....", "####.", "#...#", "#...#", ".###.",
        ],
        '7' => [
            "#####", "....#", "...#.", "..#..", ".#...", ".#...", ".#...",
        ],
        '8' => [
            ".###.", "#...#", "#...#", ".###.", "#...#", "#...#", ".###.",
        ],
        '9' => [
            ".###.", "#...#", "#...#", ".####", "....#", "...#.", ".##..",
        ],
        ' ' => [
            ".....", ".....", ".....", ".....", ".....", ".....", ".....",
        ],
        '_' => [
            ".....", ".....", ".....", ".....", ".....", ".....", "#####",
        ],
        '-' => [
            ".....", ".....", ".....", "#####", ".....", ".....", ".....",
        ],
        '+' => [
            ".....", "..#..", "..#..", "#####", "..#..", "..#..", ".....",
        ],
        '.' => [
            ".....", ".....", ".....", ".....", ".....", ".##..", ".##..",
        ],
        ',' => [
            ".....", ".....", ".....", ".....", ".##..", "..#..", ".#...",
        ],
        ':' => [
            ".....", ".##..", ".##..", ".....", ".##..", ".##..", ".....",
        ],
        '=' => [
            ".....", ".....", "#####", ".....", "#####", ".....", ".....",
        ],
        '/' => [
            ".....", "....#", "...#.", "..#..", ".#...", "#....", ".....",
        ],
        '(' => [
            "...#.", "..#..", ".#...", ".#...", ".#...", "..#..", "...#.",
        ],
        ')' => [
            ".#...", "..#..", "...#.", "...#.", "...#.", "..#..", ".#...",
        ],
        '%' => [
            "##...", "##..#", "...#.", "..#..", ".#...", "#..##", "...##",
        ],
        '@' => [
            ".###.", "#...#", "#.###", "#.#.#", "#.###", "#....", ".####",
        ],
        _ => [
            "#####", "#...#", "#...#", "#...#", "#...#", "#...#", "#####",
        ],
    };
    let mut out = [0u8; 7];
    for (o, r) in out.iter_mut().zip(rows) {
        *o = r
            .bytes()
            .fold(0u8, |acc, b| (acc << 1) | u8::from(b == b'#'));
    }
    out
}

/// Width in pixels of `text` drawn at `scale`.
pub fn text_width(text: &str, scale: usize) -> usize {
    let n = text.chars().count();
    if n == 0 { 0 } else { (n * ADVANCE - 1) * scale }
}

/// How many characters fit in `width` pixels at `scale`.
fn chars_in(width: usize, scale: usize) -> usize {
    (width / scale.max(1) + 1) / ADVANCE
}

/// `text` cut to at most `width` pixels at `scale` (whole characters).
pub fn fit(text: &str, width: usize, scale: usize) -> String {
    text.chars().take(chars_in(width, scale)).collect()
}

/// `text` broken into lines of at most `width` pixels at `scale`, at most `max_lines` of them:
/// breaks go after `_`, `,`, a space or a hyphen (not a minus sign: a `-` before a digit or
/// `.`) where possible (a word longer than a line is cut),
/// and a last line that cannot hold the rest is cut like [`fit`].
pub fn wrap(text: &str, width: usize, scale: usize, max_lines: usize) -> Vec<String> {
    let (max, max_lines) = (chars_in(width, scale).max(1), max_lines.max(1));
    let chars: Vec<char> = text.chars().collect();
    let mut lines = Vec::new();
    let mut start = 0;
    while start < chars.len() && lines.len() < max_lines {
        let rest = chars.len() - start;
        let take = if rest <= max || lines.len() + 1 == max_lines {
            rest.min(max)
        } else {
            // The last break character within the line, else a hard cut.
            // A `-` before a digit or `.` is a minus sign, which stays with its number.
            let breaks_after = |i: usize| match chars[i] {
                '_' | ',' | ' ' => true,
                '-' => !chars
                    .get(i + 1)
                    .is_some_and(|c| c.is_ascii_digit() || *c == '.'),
                _ => false,
            };
            (1..=max)
                .rev()
                .find(|&k| breaks_after(start + k - 1))
                .unwrap_or(max)
        };
        let line: String = chars[start..start + take].iter().collect();
        lines.push(line.trim_end().to_owned());
        start += take;
        while start < chars.len() && chars[start] == ' ' {
            start += 1;
        }
    }
    lines
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wrap_breaks_at_separators_and_keeps_lines_in_width() {
        let w = text_width("ACRYLIC_FEL", 1);
        assert_eq!(
            wrap("acrylic_felt_green", w, 1, 3),
            ["acrylic_", "felt_green"]
        );
        assert_eq!(wrap("mid(a, b)", 200, 1, 3), ["mid(a, b)"]);
        // No break character: hard cuts; the line limit cuts the rest.
        assert_eq!(
            wrap("abcdefghij", text_width("abcd", 1), 1, 2),
            ["abcd", "efgh"]
        );
        // A minus sign stays with its number ("0.66, 0.01, -" then "0.06" read as positive).
        let w = text_width("(0.66, 0.01, -0", 1);
        assert_eq!(
            wrap("(0.66, 0.01, -0.06)", w, 1, 3),
            ["(0.66, 0.01,", "-0.06)"]
        );
        assert_eq!(
            wrap("grease-covered", text_width("grease-cov", 1), 1, 2),
            ["grease-", "covered"]
        );
        for line in wrap("carpaint_metallic_blue,0.12,-0.5", 60, 1, 9) {
            assert!(text_width(&line, 1) <= 60, "{line}");
        }
    }

    /// The last allowed line is cut like [`fit`] (not at a break); spaces after a break or a
    /// hard cut never start the next line; at scale 2 a line holds half the characters.
    #[test]
    fn wrap_cuts_the_last_line_and_drops_leading_spaces() {
        let four = text_width("abcd", 1);
        // One line allowed: "ab_cdefgh" is cut to 4 characters, not broken after '_'.
        assert_eq!(wrap("ab_cdefgh", four, 1, 1), ["ab_c"]);
        assert_eq!(wrap("ab_cdefgh", four, 1, 2), ["ab_", "cdef"]);
        // Two spaces after a break, one after a hard cut: none leads a line.
        assert_eq!(wrap("ab  cd", text_width("abc", 1), 1, 3), ["ab", "cd"]);
        assert_eq!(wrap("abcd efgh", four, 1, 3), ["abcd", "efgh"]);
        // 35 px at scale 2 is 17 px at scale 1: (17 + 1) / 6 = 3 characters.
        assert_eq!(fit("abcdef", 35, 2), "abc");
        assert_eq!(text_width("abc", 2), 34);
        assert_eq!(wrap("abcdef", 35, 2, 3), ["abc", "def"]);
    }

    #[test]
    fn glyphs_are_distinct_and_five_wide() {
        let chars = "ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_-+.,:=/()%@";
        let gs: Vec<[u8; 7]> = chars.chars().map(glyph).collect();
        for (i, a) in gs.iter().enumerate() {
            assert!(a.iter().all(|r| *r < 32));
            assert!(
                a.iter().any(|r| *r != 0),
                "{}",
                chars.chars().nth(i).unwrap()
            );
            for b in &gs[i + 1..] {
                assert_ne!(a, b);
            }
        }
        // Every supported character has a glyph of its own, not the box of unknown ones.
        let unknown = glyph('\u{1}');
        assert_eq!(
            unknown,
            [
                0b11111, 0b10001, 0b10001, 0b10001, 0b10001, 0b10001, 0b11111
            ]
        );
        for c in chars.chars() {
            assert_ne!(
                glyph(c),
                unknown,
                "{c} is drawn as the unknown-character box"
            );
        }
        assert_eq!(glyph('~'), unknown);
        // Bit 4 is the leftmost pixel: 'L' is a left bar and a bottom line, '7' leans left.
        assert_eq!(glyph('L'), [16, 16, 16, 16, 16, 16, 31]);
        assert_eq!(glyph('7'), [31, 1, 2, 4, 8, 8, 8]);
        assert_eq!(glyph('a'), glyph('A'));
        assert_eq!(glyph(' '), [0; 7]);
        assert_eq!(text_width("ab", 2), 22);
        assert_eq!(fit("abcdef", 17, 1), "abc");
        assert_eq!(text_width(&fit("abcdef", 17, 1), 1), 17);
    }
}
