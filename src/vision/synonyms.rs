//! Open-vocabulary labels → a detector's closed class list.
//!
//! Query words (ScanNet/ScanRefer names, user text) are normalised, then tried in order:
//! exact class, synonym table, singular form, and the phrase's head noun (last word).

/// Groups of words meaning the same thing; the first entry of each group is the COCO name.
const GROUPS: &[&[&str]] = &[
    &[
        "couch",
        "sofa",
        "settee",
        "loveseat",
        "sectional",
        "sofa chair",
        "futon",
    ],
    &[
        "dining table",
        "table",
        "desk",
        "coffee table",
        "kitchen table",
        "end table",
        "side table",
        "round table",
        "work table",
        "conference table",
    ],
    &[
        "tv",
        "television",
        "monitor",
        "computer monitor",
        "screen",
        "tv screen",
        "display",
    ],
    &[
        "chair",
        "armchair",
        "office chair",
        "stool",
        "seat",
        "folded chair",
        "rocking chair",
    ],
    &["bed", "bunk bed", "double bed", "crib"],
    &["toilet", "commode", "urinal"],
    &["refrigerator", "fridge", "mini fridge", "freezer"],
    &[
        "potted plant",
        "plant",
        "houseplant",
        "flower pot",
        "pot plant",
    ],
    &[
        "cell phone",
        "phone",
        "mobile phone",
        "smartphone",
        "telephone",
    ],
    &["laptop", "notebook computer", "computer"],
    &["keyboard", "computer keyboard", "piano keyboard"],
    &["mouse", "computer mouse"],
    &["book", "books", "notebook"],
    &["bottle", "water bottle", "soap bottle", "shampoo bottle"],
    &["cup", "mug", "coffee mug", "glass", "coffee cup"],
    &["bowl", "basin"],
    &["sink", "bathroom sink", "kitchen sink", "washbasin"],
    &["backpack", "rucksack", "bag", "school bag"],
    &["handbag", "purse"],
    &["suitcase", "luggage", "travel case"],
    &["microwave", "microwave oven"],
    &["oven", "stove", "range", "kitchen stove"],
    &["clock", "wall clock", "alarm clock"],
    &["vase", "flower vase"],
    &["teddy bear", "stuffed animal", "plush toy"],
    &["person", "man", "woman", "people", "human"],
    &["umbrella"],
    &["bench", "piano bench"],
    &["toaster"],
    &["scissors"],
    &["hair drier", "hair dryer", "hairdryer"],
    &["toothbrush"],
];

/// Lower-case, `_`/`-` to spaces, collapsed whitespace.
pub fn normalize(label: &str) -> String {
    label
        .to_lowercase()
        .replace(['_', '-'], " ")
        .split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
}

fn singular(word: &str) -> Option<String> {
    if word.len() > 3 && word.ends_with("ies") {
        return Some(format!("{}y", &word[..word.len() - 3]));
    }
    if word.len() > 3 && (word.ends_with("ches") || word.ends_with("shes") || word.ends_with("xes"))
    {
        return Some(word[..word.len() - 2].to_string());
    }
    if word.len() > 2 && word.ends_with('s') && !word.ends_with("ss") {
        return Some(word[..word.len() - 1].to_string());
    }
    None
}

/// Map `label` to one of `vocabulary` (matched after normalising both). `None` means the
/// detector has no class for it.
pub fn map_to_vocabulary(label: &str, vocabulary: &[String]) -> Option<String> {
    let vocab: Vec<(String, &String)> = vocabulary.iter().map(|v| (normalize(v), v)).collect();
    let lookup = |q: &str| -> Option<String> {
        if let Some((_, orig)) = vocab.iter().find(|(n, _)| n == q) {
            return Some((*orig).clone());
        }
        for group in GROUPS {
            if group.contains(&q) {
                for member in group.iter() {
                    if let Some((_, orig)) = vocab.iter().find(|(n, _)| n == member) {
                        return Some((*orig).clone());
                    }
                }
            }
        }
        None
    };
    let q = normalize(label);
    if q.is_empty() {
        return None;
    }
    let mut candidates = vec![q.clone()];
    let words: Vec<&str> = q.split(' ').collect();
    if let Some(last) = words.last() {
        if let Some(s) = singular(last) {
            let mut w: Vec<String> = words[..words.len() - 1]
                .iter()
                .map(|s| s.to_string())
                .collect();
            w.push(s.clone());
            candidates.push(w.join(" "));
            candidates.push(s);
        }
        candidates.push(last.to_string());
    }
    candidates.iter().find_map(|c| lookup(c))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn coco() -> Vec<String> {
        include_str!("../../models/coco80.txt")
            .lines()
            .map(str::to_string)
            .collect()
    }

    #[test]
    fn maps_room_words_to_coco() {
        let v = coco();
        let m = |s: &str| map_to_vocabulary(s, &v);
        assert_eq!(m("sofa").as_deref(), Some("couch"));
        assert_eq!(m("Table").as_deref(), Some("dining table"));
        assert_eq!(m("monitor").as_deref(), Some("tv"));
        assert_eq!(m("office_chair").as_deref(), Some("chair"));
        assert_eq!(m("chairs").as_deref(), Some("chair"));
        assert_eq!(m("wooden coffee table").as_deref(), Some("dining table"));
        assert_eq!(m("cup").as_deref(), Some("cup"));
        assert_eq!(m("curtain"), None);
        assert_eq!(m("door"), None);
        assert_eq!(m(""), None);
    }

    #[test]
    fn maps_to_custom_vocabulary() {
        let v = vec![
            "person".to_string(),
            "chair".to_string(),
            "sofa".to_string(),
        ];
        assert_eq!(map_to_vocabulary("couch", &v).as_deref(), Some("sofa"));
        assert_eq!(map_to_vocabulary("armchair", &v).as_deref(), Some("chair"));
        assert_eq!(map_to_vocabulary("table", &v), None);
    }
}
